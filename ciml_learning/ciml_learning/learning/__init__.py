"""Learning: learners, model sets and files, training, online learning, snapshots, gates, serving, rollback."""

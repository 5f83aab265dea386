"""The `ciml` command: its verbs, their implementations, the bench runner and benchmarks."""

"""The core: robot description, dynamics, projection, ε (eq. 17), filters, pairing, messages, profiles, files."""

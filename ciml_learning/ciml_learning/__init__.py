"""CIML learning: contact-invariant model learning for legged robots (Grandia, Pardo, Buchli, RA-L 2018)."""

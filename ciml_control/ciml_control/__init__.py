"""CIML control: inverse-dynamics QP controller with learned model error, gait references."""

"""CIML control: inverse-dynamics QP controller with learned model error, gait references."""
from ciml_learning import quiet_interrupt_while_starting

quiet_interrupt_while_starting(("reference_generator", "id_controller"))

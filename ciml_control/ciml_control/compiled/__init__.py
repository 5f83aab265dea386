"""The 250 Hz control step compiled with numba, one module per concern; controller.py,
qp.py, feedback.py and references.LegIK are their Python interfaces:

- linalg: small dense linear algebra (Householder QR with LAPACK's conventions, Cholesky and
  minimum-norm solves) on the controller's matrices (18 × 18 at most);
- contact_space: the QR of the stance feet's Jacobian, J_cᵀ = [Q_c Q_u][R; 0], and the row space
  of Q_uᵀSᵀ (eq. 19), which the QP and the feedback linearisation share;
- feedforward_qp: the QP of eq. (18–21), its solve by the C++ core's proxsuite in the null space of
  eq. 19, and the check of the answer;
- feedback_linearization: eq. (24) and the clipping of the total torque to the limits;
- leg_ik: the gait references' leg inverse kinematics and joint rates;
- control_step: one whole step, records in and torques out (IdController.compute; the compiled
  closed loop of ciml_sim.joint_loop).

Compiled on first use and cached on disk (numba `cache=True`); the C++ core's functions are
called by address (ciml_control.native).
"""

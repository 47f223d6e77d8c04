"""A user-defined effect: friction of the lower disc that varies with its angle.

A bearing or brake surface that is slightly eccentric or uneven rubs harder at some angles
than at others.  The Coulomb and static levels of the lower disc then vary once per
revolution:

    Tc_l(theta_l) = Tc_l * (1 + a_fric * sin(theta_l + phi_fric))

Use it without editing rotorbayes:

    rotorbayes fit --model coupled est.csv --add examples/angle_friction.py:angle_friction --out f/

The physics is one plain function (numba compiles it) with the signature every hook has:
``(t, theta_u, omega_u, theta_l, omega_l, v, p, q) -> (upper, lower)``.  ``p`` holds the
built-in parameters (positions from ``rotorbayes.kernel.layout``), ``q`` this effect's own
parameters in the order they are declared below.
"""

import math

from rotorbayes import Effect, Parameter
from rotorbayes.kernel.layout import TC_L


def angle_friction_shift(t, theta_u, omega_u, theta_l, omega_l, v, p, q):
    """Shift of the friction levels [N m]: nothing on the upper disc, a once-per-revolution
    ripple of the lower disc's Coulomb (and static) level."""
    return 0.0, p[TC_L] * q[0] * math.sin(theta_l + q[1])


angle_friction = Effect(
    name="angle_friction",
    physics="the lower disc's friction level varies once per revolution with its angle "
    "(eccentric or uneven bearing/brake surface).",
    parameters=(
        Parameter("a_fric", "-", -0.9, 0.9, 0.0, "relative amplitude of the friction ripple",
                  start=0.05),
        Parameter("phi_fric", "rad", -math.pi, math.pi, 0.0, "phase of the friction ripple",
                  start=0.0, nuisance=True),
    ),
    signature="theta_l residual repeats once per revolution of the lower disc; the "
    "missing torque correlates with sin and cos of theta_l",
    configs=("coupled", "brake"),
    friction_shift=angle_friction_shift,
)

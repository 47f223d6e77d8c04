"""A user-defined effect with a state: the brake's friction falls as sliding warms it.

Sliding heats the contact; a warmer contact rubs less.  The heat (here directly the drop
of the lower disc's friction level it causes, ``z`` [N m]) rises with the sliding speed
and relaxes with a time constant:

    dz/dt = (k_warm * |omega_l| - z) / tau_warm,     z(0) = 0
    Tc_l, Ts_l  ->  Tc_l - z, Ts_l - z

so in a long slide the friction settles ``k_warm * |omega_l|`` lower, and at rest it
recovers.  A fit without it sees the friction level drift within a run.

Use it without editing rotorbayes:

    rotorbayes fit --model coupled est.csv --add examples/friction_warming.py:friction_warming

A stateful effect names its state (``state="heat"``) and gives its rate; its functions take
the state ``z`` after ``v``: ``(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q)``.  The
kernel integrates ``z`` with the rig's state by the same Runge-Kutta steps, sticking or
slipping (a model holds at most one stateful effect).
"""

from rotorbayes import Effect, Parameter


def warming_rate(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q):
    """dz/dt [N m/s]: heating by sliding, relaxing with tau_warm."""
    return (q[0] * abs(omega_l) - z) / q[1]


def warming_shift(t, theta_u, omega_u, theta_l, omega_l, v, z, p, q):
    """Shift of the friction levels [N m]: the lower disc's fall by the heat z."""
    return 0.0, -z


friction_warming = Effect(
    name="friction_warming",
    physics="the lower disc's friction level falls as sliding warms the brake (first-order "
    "heating with the sliding speed, relaxing at rest).",
    parameters=(
        Parameter("k_warm", "N m s/rad", 0.0, 0.1, 0.0,
                  "steady fall of the friction level per rad/s of sliding", start=1e-3),
        Parameter("tau_warm", "s", 0.05, 100.0, 5.0, "time constant of warming and cooling",
                  start=5.0, nuisance=True),
    ),
    signature="theta_l residual grows through long slides and the lower friction level "
    "drifts within a run; the missing torque follows time and the recent sliding speed",
    configs=("coupled", "brake"),
    friction_shift=warming_shift,
    state="heat",
    state_rate=warming_rate,
)

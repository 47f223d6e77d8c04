"""The catalogue of physical effects the model can switch on.

Every effect is already inside the compiled kernel, off at its null value, so "adding an
effect" frees its parameters instead of changing the integrator.  The diagnosis tools
(residual -> missing physics -> refit) scan this catalogue.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Effect:
    """One physical effect.

    Attributes
    ----------
    name : str
        Identifier used in the API and on the command line.
    parameters : tuple of str
        The parameters it frees (see :mod:`rotorbayes.parameters`).
    physics : str
        What it models, in one sentence.
    signature : str
        What a residual looks like when the effect is missing.
    """

    name: str
    parameters: tuple[str, ...]
    physics: str
    signature: str


CATALOGUE: dict[str, Effect] = {
    e.name: e
    for e in [
        Effect(
            "lower_asymmetric_coulomb",
            ("dTc_l",),
            "Coulomb friction of the lower disc differs between the two directions (§5.2.3).",
            "residual of theta_l drifts one way in positive slip and the other in negative "
            "slip; error grows with each reversal",
        ),
        Effect(
            "lower_asymmetric_viscous",
            ("db_l",),
            "viscous friction of the lower disc differs between the two directions (eq. 5.18).",
            "residual correlates with omega_l * sign(omega_l) differently per direction",
        ),
        Effect(
            "lower_stribeck",
            ("Ts_l", "ws_l", "delta_l"),
            "static friction above the Coulomb level, decaying with speed (negative damping).",
            "stick phases last longer than simulated; large errors right after break-away",
        ),
        Effect(
            "string_damping",
            ("c_alpha",),
            "viscous damping in the torsion of the string (§2.3 neglects it).",
            "simulated string oscillations decay too slowly; residual at the string's "
            "natural frequency",
        ),
        Effect(
            "voltage_offset",
            ("u_offset",),
            "an offset in the amplifier's output voltage.",
            "theta_u residual drifts linearly while u is near zero",
        ),
        Effect(
            "input_delay",
            ("t_delay",),
            "a time delay between the commanded and applied voltage.",
            "residual proportional to the derivative of the response; cross-correlation "
            "with u peaks at a positive lag",
        ),
        Effect(
            "motor_deadzone",
            ("u_deadzone",),
            "the motor produces no torque for small voltages.",
            "simulated upper disc moves where the measured one stays still at small |u|",
        ),
    ]
}

#: Parameters estimated in each configuration before any effect is added: the thesis's
#: stepwise method (tables 4.1-4.3) estimates the upper disc first, then the string and
#: lower disc with the upper part fixed, then the brake friction.
BASE_PARAMETERS: dict[str, tuple[str, ...]] = {
    "upper": ("k_m", "Tc_u", "dTc_u", "b_u", "db_u"),
    "coupled": ("J_l", "k_alpha", "Tc_l", "b_l"),
    "brake": ("Tc_l", "b_l", "Ts_l", "ws_l", "delta_l"),
}


def get(name: str) -> Effect:
    """Look an effect up by name, with an error that lists the catalogue."""
    try:
        return CATALOGUE[name]
    except KeyError:
        raise ValueError(
            f"unknown effect {name!r}; the catalogue has: {', '.join(CATALOGUE)}"
        ) from None

"""Layout of the compiled kernel's parameter vector, configuration codes and status codes.

The kernel receives the built-in parameters as one float64 vector ``p`` in the order of
:data:`NAMES`.  The integer constants below are its positions; user-defined effects read
base parameters from ``p`` with them (``p[TC_L]``), e.g. a friction level that varies
with angle.  The order is internal: files and the API always use names.
"""

from __future__ import annotations

#: Built-in parameter names in kernel order (base model first, then the catalogue effects).
NAMES: tuple[str, ...] = (
    "k_m", "J_u", "Tc_u", "dTc_u", "b_u", "db_u",
    "J_l", "k_alpha", "Tc_l", "dTc_l", "b_l", "db_l",
    "Ts_l", "ws_l", "delta_l", "alpha0", "c_alpha", "u_offset", "t_delay", "u_deadzone",
    "dTs_u", "ws_u", "delta_u", "tau_drive",
)  # fmt: skip
INDEX: dict[str, int] = {n: i for i, n in enumerate(NAMES)}

K_M, J_U, TC_U, DTC_U, B_U, DB_U = range(6)
J_L, K_ALPHA, TC_L, DTC_L, B_L, DB_L = range(6, 12)
TS_L, WS_L, DELTA_L, ALPHA0, C_ALPHA, U_OFFSET, T_DELAY, U_DEADZONE = range(12, 20)
DTS_U, WS_U, DELTA_U, TAU_DRIVE = range(20, 24)
N_PARAMS = len(NAMES)

#: Configuration codes of the kernel.
CFG_UPPER = 0  # string removed: upper disc only
CFG_COUPLED = 1  # both discs, motor-driven (with or without the brake)
CFG_PRESCRIBED = 2  # lower disc only, driven by a prescribed upper-disc angle

#: Status codes returned by the kernel (never an exception from compiled code).
OK = 0
BAD_PARAMETERS = 1
BLOW_UP = 2
TOO_MANY_EVENTS = 3
BAD_EFFECT = 4

STATUS_MESSAGES = {
    OK: "ok",
    BAD_PARAMETERS: "invalid parameters",
    BLOW_UP: "the solution blew up (non-finite or |omega| > 1e6 rad/s)",
    TOO_MANY_EVENTS: "more than 50 stick/slip events inside one step (Zeno behaviour)",
    BAD_EFFECT: "a user-defined effect made a friction level smaller than its asymmetry "
    "(friction would push in the direction of motion) or returned a non-finite value",
}

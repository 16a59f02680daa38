# numba source unit: the event loop's state, one record that every case of Algorithm 1 takes
# (collision/algorithm1.py: free flight, hold, release, the event step, the impact and its cases;
# collision/events.py: the collision-time search). It needs no generated name.
#
# A numba namedtuple of arrays and scalars: numba caches functions that take it (a jitclass it
# cannot), and its arrays are the loop's own (borrowed or on integrate's stack frame:
# vcirun.codegen.frame), so passing it costs no reference counting. Its scalars are the run's
# settings, fixed for the run; what changes during the run lives in its arrays (a namedtuple is
# immutable): the state itself, the contact modes, the small integer array `n` (N_HELD: the held
# contacts' count).
from collections import namedtuple

N_HELD = 0     # n[N_HELD]: how many contacts are held (mode[j] != 0)
N_STEP = 1     # n[N_STEP]: the index k of the grid step k -> k+1 being taken
N_FRESH = 2    # n[N_FRESH]: 1 when (mu_end, lt_end, ev_end) are the held contacts' values at the grid
               # state (q, p) (a held step with friction taken whole): the record reuses them
N_COUNTS = 3   # the length of n

LoopState = namedtuple("LoopState", (
    # the grid state (q, p) at the step's start (at its end once the step is taken) and the trial
    # step from it: (qt, pt) the state a map reached, vt its last stage's step velocity
    "q", "p", "qt", "pt", "vt",
    # the event step: (qh, ph) the state at the current time inside the step; at an impact pp the
    # momentum after it, d the impact law's direction, (qn, pmap) the declared reset map's (q+, p+)
    "qh", "ph", "pp", "d", "qn", "pmap",
    # per contact (NCON): held, the contact mode (0 free; held[j] != 0 means held: +1 or -1 slipping
    # in that direction, frictionless held contacts +1, 2 stuck: maps/friction.py); mu and mu_end,
    # the held contacts' normal forces at the step's start and end; imp, the impulses of a held step;
    # phis, phi_i scratch; lam and active, the impact law's impulses and the contacts at the impact
    "held", "mu", "mu_end", "imp", "phis", "lam", "active",
    # friction (FRICTION only): impt, a held step's tangential impulses; lamt, the impact law's; lt and
    # lt_end, the held contacts' tangential forces at the step's start and end; ev and ev_end, their
    # mode event values there (maps/friction.py mode_event_values); fw[0], the friction work of the
    # last held step taken or tried (counted into the record where the step is taken)
    "impt", "lamt", "lt", "lt_end", "ev", "ev_end", "fw",
    # n: counts (N_HELD); dense: the accumulation detector (_accumulating)
    "n", "dense",
    # the record (vcirun.core.record: out[O_*], info[I_*]) and the scene's parameter vector
    "out", "info", "prm",
    # the settings (vcirun.core.record.SETTINGS), fixed for the run: the grid step h, Newton's
    # tolerance and iteration cap, the event tolerance, the per-step impact cap, held contacts allowed
    "h", "ntol", "maxit", "event_tol", "max_impacts_step", "resting",
))

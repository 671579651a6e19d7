"""The flat arrays the allocation kernels exchange: one index per field.

numba passes float64 arrays to and between kernels at no cost, where objects
would need boxing; these constants name their entries. Every kernel module
imports them from here (one definition), and :mod:`..allocator` packs and
unpacks with them.
"""

from __future__ import annotations

from tiltrov_ros.core.allocation.families import FAMILY_SAMPLES
from tiltrov_ros.core.allocation.robust import GLOBAL_TARGETS

# --------------------------------------------------------------------------- allocator config
# cfg: float64[CFG_SIZE], built once per ThrustAllocator (pack_config in ..allocator).
CFG_L = 0                 # l, thruster spacing along x [m]
CFG_W = 1                 # d, thruster spacing along y [m]
CFG_K = 2                 # (l + d) / (2 sqrt2), the yaw arm of eq. (4)
CFG_FMAX = 3              # max_thrust [N]
CFG_TILT_MIN = 4          # servo range [rad]
CFG_TILT_MAX = 5
CFG_STEP = 6              # max_tilt_step [rad] (inf: none)
CFG_WEIGHTS = 7           # 6 entries: weights X Y Z K M N
CFG_AVAILABLE = 13        # 4 entries: 1.0 working, 0.0 failed
CFG_MODE = 17             # 0.0 paper, 1.0 robust
CFG_PENALTY = 18          # motion_penalty
CFG_PLANNING = 19         # 1.0: plan the servos' travel
CFG_HORIZON = 20          # planning horizon (calls), an integer as float
CFG_SIZE = 21

MODE_PAPER = 0.0
MODE_ROBUST = 1.0

# --------------------------------------------------------------------------- the tilt problem
# prob: float64[PROB_SIZE], a TiltProblem (reference: ..thrusts.TiltProblem), scaled units.
PROB_SCALE = 0            # s = max(max |tau_i|, f_max)
PROB_FMAX = 1             # f_max / s
PROB_UPPER = 2            # 4 entries: per-thruster limit (0 for a failed one)
PROB_S_COEF = 6           # 4 entries: (A1, A2, B1, B2) of the sums block
PROB_D_COEF = 10          # 4 entries: the differences block
PROB_S_TARGET = 14        # 4 entries: (u1, v1, u2, v2) of the sums block
PROB_D_TARGET = 18        # 4 entries: the differences block
PROB_TARGET_NORM2 = 22    # |W tau|^2 (scaled)
PROB_ALL_AVAILABLE = 23   # 1.0 when no thruster has failed
PROB_AVAILABLE = 24       # 4 entries: 1.0 working, 0.0 failed
PROB_TAU = 28             # 6 entries: the scaled wrench
PROB_SIZE = 34

# --------------------------------------------------------------------------- one evaluation
# rec: float64[REC_SIZE], an Evaluation (reference: ..local.Evaluation).
REC_A = 0
REC_B = 1
REC_COST = 2
REC_GRAD = 3              # 2 entries: dc/da, dc/db
REC_HESS = 5              # 3 entries: c_aa, c_ab, c_bb
REC_THRUSTS = 8           # 4 entries (scaled)
REC_BOUNDS = 12           # 4 entries: -1, 0, +1 or 2 (failed), as floats
REC_SIZE = 16

# --------------------------------------------------------------------------- previous result
# prev: float64[PREV_SIZE], what allocate() needs of ``previous``.
PREV_EXISTS = 0           # 1.0 when a previous result was given (0.0: the rest is unused)
PREV_TILTS = 1            # 2 entries: tilt_front, tilt_rear as given (non-finite: no tilts)
PREV_TRANSIT = 3          # 1.0 when previous.method == 'transit'
PREV_TARGET = 4           # 2 entries: previous.target (NaN: none)
PREV_STUCK = 6            # previous.stuck
PREV_SIZE = 7

# --------------------------------------------------------------------------- one result
# out: float64[OUT_SIZE], an AllocationResult (reference: ..results.AllocationResult).
OUT_THRUSTS = 0           # 4 entries [N]
OUT_TILTS = 4             # 2 entries [rad]
OUT_ACHIEVED = 6          # 6 entries, eq. (4)
OUT_FEASIBLE = 12         # 1.0 / 0.0
OUT_METHOD = 13           # index into METHODS
OUT_DISC = 14             # discriminant of (**) (NaN where it does not apply)
OUT_ERROR = 15            # weighted error
OUT_TARGET = 16           # 2 entries (NaN: none)
OUT_STUCK = 18
OUT_SIZE = 19

#: AllocationResult.method by code (OUT_METHOD).
METHODS = ('exact', 'family', 'zero', 'saturated', 'pseudo', 'optimized', 'fixed_tilt',
           'transit', 'previous')
METHOD_CODE = {name: float(i) for i, name in enumerate(METHODS)}

# --------------------------------------------------------------------------- paper fallback
# The Moore-Penrose pseudo-inverse of A (eq. (5)), 8 x 6 row-major, as numpy computes it
# (the paper mode's xi = 0 solution, Section 3.2 case 3), after the fields above.
CFG_PINV = CFG_SIZE       # 48 entries
CFG_FULL_SIZE = CFG_PINV + 48

# --------------------------------------------------------------------------- exact solutions
# conf: float64[n, CONF_SIZE], one exact solution a row (reference: ..decomposition.ExactConfig).
CONF_THRUSTS = 0          # 4 entries [N]
CONF_TILTS = 4            # 2 entries [rad] (NaN for the zero wrench's free pairs)
CONF_FAMILY = 6           # 1.0: a member of a one-parameter family
CONF_FREE = 7             # 2 entries: 1.0 when the pair has no thrust (its tilt is free)
CONF_SIZE = 9

#: Candidate slots of one wrench (reference: ..closed_form.solve_batch): 4 roots of (**),
#: then the families F1 and F2 (samples, 10 kink points, 2 x MAX_AIMS aimed tilts each)
#: and F3 (samples).
ROOT_SLOTS = 4
MAX_AIMS = 3
KINKS = 10
FAMILY_SLOTS = FAMILY_SAMPLES + KINKS + 2 * MAX_AIMS
MAX_SLOTS = ROOT_SLOTS + 2 * FAMILY_SLOTS + FAMILY_SAMPLES
#: A wrench's exact solutions and its snapped neighbour's (reference: ..allocator.allocate).
MAX_CONFIGS = 2 * MAX_SLOTS
#: Equivalent tilts per candidate: gamma + {0, pi, -pi} per pair.
VARIANTS = 9

# --------------------------------------------------------------------------- planner targets
# targets: float64[n, TGT_SIZE] (reference: ..planner.Target).
TGT_A = 0
TGT_B = 1
TGT_COST = 2
TGT_SIZE = 3
#: Twins of one tilt within a range of at most 2 pi: angle + k pi for three k.
TWINS = 3
MAX_TARGETS = VARIANTS * MAX_CONFIGS + GLOBAL_TARGETS * TWINS * TWINS + 1

# --------------------------------------------------------------------------- work buffers
# buf: float64[BUF_SIZE], one per ThrustAllocator: every scratch array of a call,
# carved by kernels/allocate.py (nothing is allocated per call).
BUF_CONFIGS = 0                                        # MAX_CONFIGS x CONF_SIZE
BUF_SCRATCH = BUF_CONFIGS + MAX_CONFIGS * CONF_SIZE   # MAX_SLOTS x CONF_SIZE
BUF_UV = BUF_SCRATCH + MAX_SLOTS * CONF_SIZE          # MAX_SLOTS x 2: (U, V) per slot
BUF_TARGETS = BUF_UV + MAX_SLOTS * 2                  # MAX_TARGETS x TGT_SIZE
BUF_STARTS = BUF_TARGETS + MAX_TARGETS * TGT_SIZE     # (MAX_CONFIGS + 3) x 2
BUF_PROB = BUF_STARTS + (MAX_CONFIGS + 3) * 2         # PROB_SIZE
BUF_REC = BUF_PROB + PROB_SIZE                        # REC_SIZE
BUF_RECS = BUF_REC + REC_SIZE                         # GLOBAL_TARGETS x REC_SIZE
BUF_BOX = BUF_RECS + GLOBAL_TARGETS * REC_SIZE        # 2 x 2: this call's reach
BUF_SEARCH_BOX = BUF_BOX + 4                          # 2 x 2: the search's box
BUF_AIMS = BUF_SEARCH_BOX + 4                         # 2 x MAX_AIMS
BUF_PLAN = BUF_AIMS + 2 * MAX_AIMS                    # 5: Plan.tilts, Plan.target
BUF_TAU = BUF_PLAN + 5                                # 6: the snapped wrench
BUF_ANCHOR = BUF_TAU + 6                              # 2: the previous tilts in range
BUF_KEPT = BUF_ANCHOR + 2                             # 2: the target of a travel under way
BUF_FULL = BUF_KEPT + 2                               # 2 x 2: the whole tilt range
BUF_VALUES = BUF_FULL + 4                             # 16: family parameters to try
BUF_KEYS = BUF_VALUES + 16                            # MAX_TARGETS x 2: rounded tilts
BUF_PREV = BUF_KEYS + MAX_TARGETS * 2                 # PREV_SIZE: a batch row's previous
BUF_OUT = BUF_PREV + PREV_SIZE                        # OUT_SIZE: the paper incumbent
BUF_OUT2 = BUF_OUT + OUT_SIZE                         # OUT_SIZE: a batch row's result
BUF_SIZE = BUF_OUT2 + OUT_SIZE
# ibuf: int64[IBUF_SIZE]: an evaluation's hint (reference: ..local.evaluate).
IBUF_HINT = 0
IBUF_SIZE = 4

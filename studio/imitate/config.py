"""The imitation stage's configs and presets: losses, gradient search, refinement, block sweep, stills, sequences.

Plain dataclasses with no torch import, so the command line builds its flags from them without loading the engine
(``studio.cli.flags``: a field's trailing comment is its help and may end with its range). The engine modules that
use them: :mod:`studio.imitate.losses`, :mod:`~studio.imitate.search`, :mod:`~studio.imitate.refine`,
:mod:`~studio.imitate.sweep`, :mod:`~studio.imitate.still` and :mod:`~studio.imitate.sequence`.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from studio.sim.crop_pad import PAD

COMPONENTS = ("total", "base", "mae", "iou_loss", "clip", "expr", "exp_iou", "exp_clip", "temporal")


@dataclass(frozen=True)
class LossConfig:
    """Weights and crop settings of the image losses (paper defaults, DESIGN §4)."""

    w_mae: float = 0.06  # base: weight of the mean absolute error of the crops
    w_iou: float = 0.4  # base: weight of 1 − soft IoU of the crops
    w_clip: float = 0.02  # base: weight of 1 − cosine of the CLIP embeddings of the crops
    w_exp_iou: float = 1.0  # expressive: weight of 1 − soft IoU inside the expressive region M
    w_exp_clip: float = 0.05  # expressive: weight of 1 − cosine of the CLIP embeddings of M⊙pred and M⊙target
    w_temporal: float = 0.2  # temporal: weight of ‖θ_i − θ*_{i−1}‖² (rad²)
    use_clip: bool = True  # False: leave both CLIP terms out (reported as NaN); no CLIP model needed
    crop_size: int = 256  # side of the aligned crops, pixels (paper 256; e.g. 64-128 on CPU)
    pad: float = PAD  # padding around each shadow box, pixels of a 256-pixel image (scaled with the image side)
    box_threshold: float = 0.5  # prediction pixels above this probability define its box
    eps: float = 1e-6  # keeps the soft IoU finite on empty images

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class SearchConfig:
    """Gradient search settings (paper defaults; see ``CPU_SEARCH`` for the quick CPU preset)."""

    # bounds of every budget: what 2 cores and ~24 GiB finish in hours (a batch is ~2 MB each through the 128²
    # self-model and back: 2048 is ~4 GB; more steps only cost time, bounded at a few hours)
    batch: int = 256  # joint vectors optimised together [1, 2048]
    iterations: int = 2000  # gradient steps [1, 100000]
    lr: float = 0.05  # Adam step size on the unconstrained parameters φ (0, 10]
    init_noise: float = 0.05  # std (rad) around a given initial pose (sequence frames after the first) [0, 3.2]
    include_rest: bool = True  # one sample of the batch starts at the rest pose
    seed: int = 0  # initialisation seed [0, 4294967295]
    log_every: int = 10  # record the loss curve every this many steps [1, 100000]


CPU_SEARCH = SearchConfig(batch=32, iterations=150, lr=0.08)  # seconds on 2 CPU cores with the 128² model
STUDIO_SEARCH = SearchConfig(batch=32, iterations=50, lr=0.08)  # stills after the block sweep (studio preset)
PAPER_SEQUENCE_FIRST = SearchConfig(batch=500, iterations=3000)  # first frame of a sequence
PAPER_SEQUENCE_NEXT = SearchConfig(batch=128, iterations=1200)  # later frames, from the previous optimum


@dataclass(frozen=True)
class RefineConfig:
    """Hill-climbing schedule (paper defaults)."""

    method: str = "hill"  # "hill": the paper's hill climbing; "cmaes": CMA-ES (studio.imitate.cmaes) per restart
    restarts: int = 8  # hill: chains (the paper's restarts), run in parallel; cmaes: runs, one after another [1, 64]
    steps: int = 1000  # hill: proposals per chain; cmaes: generations per run [0, 100000]
    popsize: int = 16  # cmaes: candidates per generation [2, 1024]
    restart_noise: float = 0.25  # std, rad, of the chains' start around the best pose (chain 0 on it) [0, 3.2]
    sigma0: float = 0.08  # initial proposal std (cmaes: initial step size), rad (0, 3.2]
    decay: float = 0.995  # hill: σ multiplier per step (0, 1]
    sigma_min: float = 0.01  # hill: σ floor, rad [0, 3.2]
    seed: int = 0  # proposal noise seed [0, 4294967295]
    log_every: int = 10  # record the best loss every this many steps [1, 100000]

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"refinement method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.restarts < 1 or self.steps < 0 or self.popsize < 2:
            raise ValueError("refinement needs restarts ≥ 1, steps ≥ 0 and popsize ≥ 2")


METHODS = ("hill", "cmaes")  # RefineConfig.method
PAPER_REFINE = RefineConfig()  # the paper's schedule: 8 hill-climbing chains × 1000 isotropic proposals
CPU_REFINE = RefineConfig(method="cmaes", restarts=1, steps=150, popsize=16, sigma0=0.1)  # the studio's default


@dataclass(frozen=True)
class SweepConfig:
    """How many poses are swept and how hard (the studio's defaults; ``starts=0`` turns the sweep off)."""

    starts: int = 4  # distinct retrieved poses swept, best first (0: no sweep, the paper's method) [0, 64]
    draws: int = 1024  # settings drawn for a finger's joints per block [1, 16384]
    wrist_draws: int = 256  # settings drawn for the wrist (one joint) per pass [1, 16384]
    local_share: float = 0.25  # share of the draws taken near the block's current setting, not uniform [0, 1]
    local_sigma: float = 0.15  # std, rad, of those local draws (clipped to the limits) (0, 3.2]
    passes: int = 3  # at most this many passes over all blocks; stops after a pass that improves nothing [1, 100]
    checks: int = 16  # a block's best improving draws checked for collisions, best first, before moving on [1, 1024]
    seed: int = 0  # seed of the draws [0, 4294967295]

    def __post_init__(self) -> None:
        if self.starts < 0 or self.draws < 1 or self.wrist_draws < 1 or self.passes < 1 or self.checks < 1:
            raise ValueError("sweep needs starts ≥ 0 and draws, wrist_draws, passes, checks ≥ 1")
        if not 0.0 <= self.local_share <= 1.0 or self.local_sigma <= 0:
            raise ValueError("sweep local_share must be in [0, 1] and local_sigma > 0")


PAPER_SWEEP = SweepConfig(starts=0)  # the paper has no sweep


@dataclass(frozen=True)
class JointConfig:
    """Refining a show's keyframes together within their reach of one another on the show's clock
    (:mod:`studio.imitate.joint_refine`; ``generations=0`` without ``both_orders`` turns it off, the paper's one
    keyframe after another)."""

    generations: int = 0  # CMA-ES generations per window of keyframes (0: off) [0, 100000]
    window: int = 3  # consecutive keyframes refined together at a time [2, 16]
    popsize: int = 32  # candidate pose sets per generation [2, 1024]
    sigma0: float = 0.1  # initial step size, rad (0, 3.2]
    seed: int = 0  # proposal noise seed [0, 4294967295]
    both_orders: bool = False  # also pose keyframes last to first; refine whichever order's sum is lower (2× time)

    def __post_init__(self) -> None:
        if self.generations < 0 or not 2 <= self.window <= 16 or self.popsize < 2 or not 0 < self.sigma0 <= 3.2:
            raise ValueError("joint refinement needs generations ≥ 0, 2 ≤ window ≤ 16, popsize ≥ 2, 0 < sigma0 ≤ 3.2")

    @property
    def enabled(self) -> bool:
        """Whether a show's keyframes take this step at all: refined together, or posed in both orders (the better
        order kept, refined by ``generations``, which may be 0)."""
        return self.generations > 0 or self.both_orders


@dataclass(frozen=True)
class ImitateConfig:
    """What ``Imitator.imitate`` does around the search and the refinement (defaults: the studio's method;
    :data:`PAPER_IMITATE`: the paper's)."""

    candidates: int = 4  # distinct best poses refined, each with the full refinement schedule [1, 64]
    retrieve: bool = True  # answer first from the retrieval index and seed the search with its best distinct poses
    select: str = "rendered"  # pick the unrefined pose and the candidates by "rendered" shadow loss or "model" loss

    def __post_init__(self) -> None:
        if self.candidates < 1:
            raise ValueError(f"candidates must be ≥ 1 (distinct search results to refine), got {self.candidates}")
        if self.select not in ("rendered", "model"):
            raise ValueError(f'select must be "rendered" or "model", got {self.select!r}')


PAPER_IMITATE = ImitateConfig(retrieve=False, select="model")  # sampled search batch, best by the self-model's loss


MODES = ("independent", "sequential")


@dataclass(frozen=True)
class SequenceConfig:
    """How a sequence of keyframes is optimised (paper sizes: the GPU preset; ``CPU_SEQUENCE`` for 2 CPU cores)."""

    mode: str = "sequential"  # "independent" (each keyframe from scratch) | "sequential" (from the previous optimum)
    expressive: bool = True  # add the expressive term L_expr on each keyframe's expressive region
    temporal: bool = True  # add L_temp = w_temporal·‖θ − θ*_{k−1}‖² (LossConfig) to search and refinement, k ≥ 1
    first: SearchConfig = PAPER_SEQUENCE_FIRST  # search of the first keyframe (every keyframe when independent)
    next: SearchConfig = PAPER_SEQUENCE_NEXT  # sequential, later keyframes: from θ*_{k−1} + N(0, init_noise)
    refine: RefineConfig = RefineConfig()  # hill climbing of each keyframe on the rendered shadow
    candidates: int = 4  # distinct best search results refined per keyframe, the best kept [1, 64]
    refine_enabled: bool = True  # False: keep the searched poses (no rendered-shadow refinement)
    retrieve: bool = False  # a keyframe searched from scratch starts from retrieval + block sweep (the still method)
    sweep: SweepConfig = SweepConfig()  # the block sweep of those seeds (retrieve; starts=0: retrieval alone)
    keep_clock: bool = True  # keep each keyframe within the servos' reach of every posed one at the show's clock
    clock_margin: float = 0.9  # share of a transition's time the reach is computed for (room for the planner) (0, 1]
    joint: JointConfig = JointConfig()  # then refine the keyframes together within that reach (keep_clock only)

    def __post_init__(self) -> None:
        if not 0 < self.clock_margin <= 1:
            raise ValueError(f"clock_margin is a share of a transition's time in (0, 1], not {self.clock_margin}")
        if self.mode not in MODES:
            raise ValueError(f"mode must be 'independent' or 'sequential', not {self.mode!r}")
        if self.candidates < 1:
            raise ValueError(f"candidates must be ≥ 1 (distinct search results to refine), got {self.candidates}")


PAPER_SEQUENCE = SequenceConfig(keep_clock=False)  # the paper's sizes (GPU): first 500 × 3000, next 128 × 1200,
# 8 × 1000 refinement, and no clock (the paper stretches nothing and checks nothing: its poses are chosen first)
# The studio preset (1 torch thread, shipped 128² model), benchmarks/bench_sequence.py on the six DAVIS sequences:
# sequential +Exp+Temp L_base + L_expr 0.550, independent 0.483, transition success 9/9 vs 0/9. Every keyframe is
# refined like a still (CMA-ES, CPU_REFINE): against 8 hill-climbing chains × 500 steps (0.563 / 0.489 then) it is
# lower on both rows and needs 2,400 instead of 4,000 renders a keyframe, and a still in a project, a keyframe
# searched from scratch and `imitate` are one search. Seeding the keyframes searched from scratch (retrieve) and
# searching them 32 × 50 instead of 32 × 150 unseeded: 0.569 → 0.563 and 0.520 → 0.489 (hill); later keyframes:
# 32 × 100 instead of 16 × 60 changes L_base by < 0.003 and doubles the time.
CPU_SEQUENCE = SequenceConfig(
    first=STUDIO_SEARCH,  # 32 × 50: after the seeds, as for a still
    next=SearchConfig(batch=16, iterations=60, lr=0.08),
    refine=CPU_REFINE,  # CMA-ES 1 × 150 generations of 16, as for a still
    candidates=4,
    retrieve=True,  # keyframes searched from scratch start from retrieval + block sweep, as still targets do
    joint=JointConfig(generations=200, both_orders=True),  # then together within their reach, the better order
)

STUDIO = "studio"  # the default preset's name
PRESETS = {STUDIO: CPU_SEQUENCE, "paper": PAPER_SEQUENCE}  # --preset on every face: the budgets of every keyframe
PRESET_WORDS = {  # what each preset is, in the words of --preset's help and the Optimise panel's budget list
    STUDIO: "the studio's method on 2 CPU cores (retrieval, block sweep, seeded search, CMA-ES refinement)",
    "paper": "the paper's method and sizes (sampled search 500 × 3000, 128 × 1200 later, hill climbing 8 × 1000; "
    "for a GPU)",
}


def still_configs(cfg: SequenceConfig) -> tuple[SearchConfig, RefineConfig, ImitateConfig, SweepConfig]:
    """The configs of ``Imitator`` that search and refine a still the way ``cfg`` searches a keyframe from scratch:
    its first search, refinement, candidates, retrieval and sweep (the unrefined pose picked on the renderer when
    retrieval seeds the search, by the self-model otherwise, as a sequence picks it)."""
    imitate = ImitateConfig(candidates=cfg.candidates, retrieve=cfg.retrieve,
                            select="rendered" if cfg.retrieve else "model")  # fmt: skip
    return cfg.first, cfg.refine, imitate, cfg.sweep


@dataclass(frozen=True)
class LivePoseConfig:
    """How one live frame becomes a pose."""

    budget_s: float = 0.04  # seconds for one frame's pose (retrieval + refinement; refinement stops when spent) (0, 10]
    shortlist: int = 48  # retrieval poses rendered and scored exactly per frame [1, 4096]
    refine_steps: int = 40  # at most this many hill-climbing steps per frame (the budget usually ends them) [0, 10000]
    refine_chains: int = 4  # hill-climbing chains run together [1, 64]
    refine_sigma: float = 0.05  # proposal std of the refinement, rad (0, 1]
    w_temporal: float = LossConfig.w_temporal  # weight of ‖θ − θ_prev‖² against the previous answer (rad²) [0, 100]
    path_checks: int = 8  # collision checks along the straight path from the commanded pose to an answer [0, 100]
    seed: int = 0  # refinement noise seed [0, 4294967295]

    def __post_init__(self) -> None:
        if not 0 < self.budget_s <= 10 or not 1 <= self.shortlist <= 4096 or not 0 <= self.refine_steps <= 10000:
            raise ValueError("live pose: budget_s must be in (0, 10] s, shortlist in [1, 4096], refine_steps ≥ 0")
        if not 1 <= self.refine_chains <= 64 or not 0 < self.refine_sigma <= 1 or not 0 <= self.w_temporal <= 100:
            raise ValueError("live pose: refine_chains in [1, 64], refine_sigma in (0, 1] rad, w_temporal in [0, 100]")
        if not 0 <= self.path_checks <= 100:
            raise ValueError("live pose: path_checks must be in [0, 100]")

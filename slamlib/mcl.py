"""Monte Carlo localization in an occupancy grid: MCL, Augmented MCL, KLD-sampling.

A particle is a pose hypothesis ``[x, y, theta]``; a set of ``M`` particles is an
``(M, 3)`` array with log-weights ``(M,)``. One filter step (:func:`mcl_step`)

1. moves every particle with a sample of the odometry motion model (Table 5.6),
2. weights it by the likelihood of the laser scan, computed either with the
   likelihood field (Table 6.3, fast: one table look-up per beam) or with the
   beam model (Table 6.1, slow: one ray cast per beam),
3. resamples (low-variance resampling, Table 4.4) when the effective sample
   size drops below ``resample_threshold * M``.

:func:`augmented_mcl_step` (the default of :func:`run_mcl`) also lets the robot
be somewhere else than the belief says. Its prior is the mixture
``(1 - p) bel + p U`` of the belief and a uniform pose over the free space, with
``p = max(p_min, 1 - w_fast / w_slow)`` (Table 8.3's rule, with a floor); new
poses of the uniform component are drawn from the scan's likelihood (sensor
resetting, Lenser and Veloso 2000; the dual proposal of Mixture-MCL, Thrun et
al. 2001) and the component's share of the posterior is computed by Bayes'
rule, ``p Z_U / (p Z_U + (1 - p) w_avg)``, where ``w_avg`` is how well the
belief explains the scan and ``Z_U`` how well a uniform pose does. A filter in
the right place explains the scan far better than a random pose, so almost
nothing is injected; a filter in the wrong place explains it worse, and the new
poses, which lie where the scan fits the map, take over. This recovers from a
kidnapping and from a global localization that settled on a look-alike place.
:func:`kld_mcl_step` chooses the number of particles at every step from the
number of histogram bins they occupy (Table 8.4).

When it resamples, :func:`augmented_mcl_step` keeps every mode of the belief
(a connected cluster of particles) that still has a posterior mass of at least
``mode_floor``, with at least ``mode_particles`` particles that share the mode's
mass (mode-preserving resampling). Plain resampling gives a mode ``M W_c``
particles, so a mode that a few unusual scans (people, an open door, a changed
piece of the map) make improbable loses every particle, and a look-alike place
that fits those scans better takes over for good; kept, the right mode wins
again once the scans fit it. The weighted particles represent the same
posterior; only the number of particles per mode changes.

The step's estimate is the weighted mean of the heaviest cluster of particles
(as ROS ``amcl`` reports), not the mean of all particles, which lies between the
clusters while the belief is multi-modal. The estimate reports its own ambiguity:
the mass of the heaviest mode and the number of modes (:func:`particle_modes`,
``MCLStepInfo.mode_mass`` / ``n_modes``, ``MCLResult.ambiguity``). That mass is a
posterior given the particles: it says nothing about poses no particle covers, so
early in global localization a look-alike place can hold nearly all of it.

Scans of a log are turned into filter steps by :func:`odometry_steps`: the
control of a step is the odometry increment since the last *used* scan, and a
scan is skipped while the robot has moved less than ``min_translation`` and
turned less than ``min_rotation`` (its odometry is merged into the next step).
Filtering the same scan twice from the same place would count the same evidence
twice and make the cloud over-confident, so MCL implementations usually update
only after a minimum motion.

Every function is vectorised over particles: no Python loop runs over them.

References
----------
Thrun, Burgard & Fox, *Probabilistic Robotics* (2005), Table 8.2 (MCL),
Table 8.3 (Augmented MCL), Table 8.4 (KLD-sampling MCL), Tables 6.1 and 6.3
(measurement models), Table 5.6 (odometry motion model), Table 4.4 (low-variance
resampling). D. Fox, "KLD-Sampling: Adaptive Particle Filters", NIPS 14 (2001).
A. Milstein, J. N. Sanchez and E. T. Williamson, "Robust global localization using
clustered particle filtering", AAAI 2002 (particles grouped in clusters that keep
their own weight and are resampled separately).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from scipy import ndimage
from scipy.special import logsumexp
from scipy.stats import norm

from ._checks import as_array, as_index, as_scalar, as_scan, check_rng, check_type
from .angles import circular_mean, wrap_angle
from . import maps, particle, sensors
from .motion import odometry_from_poses, odometry_motion, sample_motion_model_odometry

__all__ = [
    "MCLParams",
    "AugmentedParams",
    "KLDParams",
    "MCLModel",
    "MCLState",
    "MCLStepInfo",
    "MCLResult",
    "prepare_mcl",
    "odometry_steps",
    "mcl_initialize",
    "scan_log_likelihood",
    "mcl_step",
    "augmented_mcl_step",
    "kld_sample_size",
    "kld_mcl_step",
    "particle_summary",
    "particle_modes",
    "scan_endpoints",
    "endpoint_distances",
    "run_mcl",
]

_MODELS = ("likelihood_field", "beam")
_VARIANTS = ("mcl", "augmented", "kld")
_PROPOSALS = ("sensor", "uniform")
_MODE_BUDGET = 0.5  # at most this share of the particles goes to the minimum shares of modes
_MODE_REPORT = 0.01  # modes with less mass are not counted in MCLStepInfo.n_modes
_CONFIDENCE_RADIUS = 0.5  # [m] MCLStepInfo.confidence: posterior mass within this distance of the estimate
_CLUSTER_CELL = 1.0  # [m] cells of the position histogram that finds the clusters (modes) of the belief


# --------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class AugmentedParams:
    """Parameters of Augmented MCL (Table 8.3) with sensor resetting.

    The prior probability that the robot is somewhere else than the belief says
    is ``p = max(p_min, 1 - w_fast / w_slow)``; the share of new poses in the
    posterior is then ``p Z_U / (p Z_U + (1 - p) w_avg)`` (see
    :func:`augmented_mcl_step`).

    Defaults. ``p_min = 0.01``: one update in a hundred (one per 20 m of travel
    at 0.2 m per update) the filter allows that it is somewhere else than the
    belief says. The rate trades recovery against stability, and
    ``benchmarks/mcl_study.py`` and ``benchmarks/mcl_success.py`` measure both
    sides (chapter 5): a rarer rate (``1e-4``) is meant to keep a filter that
    is right from being handed to a look-alike place that explains a few scans
    better (people in the way, a door left open), but on windows of 150
    updates it did no measurably better, while a filter that has settled on a
    look-alike leaves it only rarely: over the whole of Wean Hall log 2, whose
    first part is ambiguous, the rarer rate ends near the robot far less
    often. Table 8.3's adaptive term is off
    (``alpha_slow = alpha_fast = 0``): on the Wean Hall logs the average likelihood of a filter in the right place varies from scan to scan
    (chapter 5 measures it), so ``1 - w_fast / w_slow`` stays well above zero
    during normal tracking for any of the usual decay rates, which keeps
    look-alike places populated and made the estimate hop between them. Choose
    ``alpha_slow < alpha_fast`` to switch it on (the Wean Hall chapter does so
    for a kidnapping).

    Attributes
    ----------
    alpha_slow, alpha_fast : float
        Decay rates of the long- and short-term averages of the measurement
        likelihood, ``0 <= alpha_slow <= alpha_fast <= 1``: ``w_fast`` follows
        the last ``~1/alpha_fast`` updates, ``w_slow`` the last
        ``~1/alpha_slow``. Equal rates keep ``w_fast = w_slow`` (no adaptive
        injection).
    proposal : {"sensor", "uniform"}
        Where injected particles come from. ``"uniform"`` draws them uniformly
        over the free space (Table 8.3). ``"sensor"`` draws them from
        the current scan's likelihood: ``candidates`` uniform poses are weighted
        by the (tempered) scan likelihood and the injected particles are drawn
        from them in proportion to the weights, so they land where the scan
        fits the map (sensor resetting, Lenser and Veloso 2000; the sensor-based
        proposal of Mixture-MCL, Thrun et al. 2001).
    candidates : int
        Number of uniform poses weighted by the scan for the ``"sensor"``
        proposal (ignored for ``"uniform"``).
    p_min : float
        Smallest prior probability, per update, that the robot is somewhere
        else than the belief says: ``p = max(p_min, 1 - w_fast / w_slow)``.
    average_start : {"first", "zero"}
        Where ``w_slow`` and ``w_fast`` start. ``"zero"`` is Table 8.3: both
        start at 0, so ``w_slow`` lags ``w_fast`` and nothing is injected for
        about ``1 / alpha_slow`` updates. ``"first"`` starts both at the first
        update's ``w_avg``, so the test works from the first update.
    """

    alpha_slow: float = 0.0
    alpha_fast: float = 0.0
    proposal: str = "sensor"
    candidates: int = 10_000
    p_min: float = 0.01
    average_start: str = "first"

    def __post_init__(self):
        a_s = as_scalar(self.alpha_slow, "alpha_slow", nonnegative=True)
        a_f = as_scalar(self.alpha_fast, "alpha_fast", nonnegative=True)
        if not (a_s <= a_f <= 1.0):
            raise ValueError(f"alpha_slow and alpha_fast must satisfy 0 <= alpha_slow <= alpha_fast <= 1, got {a_s}, {a_f}")
        pm = as_scalar(self.p_min, "p_min", nonnegative=True)
        if pm >= 1.0:
            raise ValueError(f"p_min must be in [0, 1), got {pm}")
        if self.proposal not in _PROPOSALS:
            raise ValueError(f"proposal must be one of {_PROPOSALS}, got {self.proposal!r}")
        if self.average_start not in ("first", "zero"):
            raise ValueError(f"average_start must be 'first' or 'zero', got {self.average_start!r}")
        as_index(self.candidates, "candidates", lower=1)


@dataclass(frozen=True)
class KLDParams:
    """Parameters of KLD-sampling (Table 8.4).

    Attributes
    ----------
    epsilon : float
        Bound on the Kullback-Leibler divergence between the sample-based and
        the true posterior.
    delta : float
        The bound holds with probability ``1 - delta``.
    bin_size : tuple of float
        Histogram bin size ``(dx [m], dy [m], dtheta [rad])``.
    n_min, n_max : int
        Smallest and largest number of particles.
    chunk : int
        Particles are drawn, moved and binned ``chunk`` at a time (vectorised);
        the count is then cut exactly where Table 8.4's one-at-a-time loop
        would have stopped.
    """

    epsilon: float = 0.05
    delta: float = 0.01
    bin_size: tuple[float, float, float] = (0.5, 0.5, np.deg2rad(10.0))
    n_min: int = 200
    n_max: int = 10_000
    chunk: int = 1000

    def __post_init__(self):
        as_scalar(self.epsilon, "epsilon", positive=True)
        d = as_scalar(self.delta, "delta", positive=True)
        if d >= 1.0:
            raise ValueError(f"delta must be in (0, 1), got {d}")
        b = as_array(self.bin_size, "bin_size", (3,))
        if np.any(b <= 0):
            raise ValueError(f"bin_size must be positive, got {tuple(b)}")
        lo = as_index(self.n_min, "n_min", lower=1)
        as_index(self.n_max, "n_max", lower=lo)
        as_index(self.chunk, "chunk", lower=1)


@dataclass(frozen=True)
class MCLParams:
    """Parameters of Monte Carlo localization with a laser range finder.

    Attributes
    ----------
    n_particles : int
        Number of particles ``M`` (the initial number for KLD-sampling). The
        default suits global localization on a floor of a building (the CMU
        Wean Hall map has 437 m^2 of free space) with :func:`augmented_mcl_step`,
        whose sensor-based new particles find the robot again if the start
        missed it; plain MCL from a uniform start found the robot in 7 of 20
        seeds with 10 000 particles and 14 of 20 with 20 000 on Wean Hall log 1
        (``benchmarks/mcl_success.py``). Position tracking needs far fewer.
    alpha : tuple of 4 float
        Odometry motion noise ``[a1, a2, a3, a4]`` in the variance form of
        Table 5.6 (``rot1`` noise variance ``a1 rot1^2 + a2 trans^2``, ...).
    model : {"likelihood_field", "beam"}
        Measurement model: the likelihood field (Table 6.3) or the beam model
        with ray casting (Table 6.1).
    ray_cache_angles : int
        Beam model only: the ray casting is pre-cached (Sec. 6.3.4,
        :func:`~slamlib.sensors.range_table`) per cell of the free space and
        direction, in this many direction bins over the circle; ``0`` casts
        every beam of every particle exactly. Each place and direction is cast
        once, the first time a particle asks for it, so a run pays for the
        places its particles visit.
    beam_step : int
        Use every ``beam_step``-th beam of a scan (10 turns 180 beams into 18).
    z_max : float
        Maximum range [m]; longer readings are clipped to ``z_max`` and count as
        max-range readings (the likelihood field ignores them).
    sigma_hit : float
        Standard deviation of the hit component [m].
    lambda_short : float
        Rate of the short-reading component [1/m] (beam model only).
    w_hit, w_short, w_max, w_rand : float
        Mixture weights; the likelihood field uses ``w_hit`` and ``w_rand``.
    max_dist : float
        Distances to the nearest obstacle are clipped at ``max_dist`` [m] in the
        likelihood field.
    likelihood_exponent : float
        The scan likelihood is raised to this power (tempered) before it
        multiplies the weights: beams of a real scan are not independent, and
        the product of their likelihoods is far too peaked (Sec. 6.3.4). The
        default, 0.1, was chosen against 0.2 and 0.05 on the trials of
        ``benchmarks/mcl_study.py`` and checked on sets the choice had not
        seen (trials of 150 updates, the whole of both logs with
        ``benchmarks/mcl_success.py``, ``benchmarks/mcl_holdout.py``);
        chapter 5 shows the comparison. A flatter likelihood keeps a look-alike
        place in the belief until the scans tell it apart instead of betting on
        one. 0.05, run on the same evaluations, was confidently wrong at fewer
        updates still (at none on the study's 40-update trials) but lost
        strict successes, since it converges more slowly. It does not help on
        every set, so 0.1 stays; a user who counts a confidently wrong
        estimate as the worse failure has the measured case for 0.05 there.
        Twice the beams (``beam_step = 5``) with the exponent halved to 0.05,
        the same weight per scan spread over more beams, did not help on every
        set either (``--configs "twice the beams, tau 0.05"``): 88 of 100
        simulated drives and confidently wrong at 4 updates against 85 and 17,
        but 4 of 20 log starts against 6.
    resample_threshold : float
        Resample when ``ESS < resample_threshold * M``; ``1.0`` resamples at
        every step as in Table 8.2.
    min_translation, min_rotation : float
        A scan updates the filter only once the odometry has moved at least
        ``min_translation`` [m] or turned ``min_rotation`` [rad] since the last
        update (:func:`odometry_steps`).
    sensor_offset : float
        Forward offset of the laser from the robot's centre [m].
    range_bias : float
        Beam model only: added to every ray-cast range below ``z_max``
        (clipped at ``z_max``), so the expected range ``z*`` of Table 6.1 is
        ``ray_cast + range_bias``. The rays stop at the face of the first
        occupied cell, which in a map whose walls were drawn thick lies in
        front of the surface the laser sees. 0 (the default) is the
        book's model; :data:`slamlib.datasets.cmu.CMU_RANGE_BIAS` is the
        value measured on the Wean Hall map. The likelihood field has no use
        for it: an endpoint inside a wall's occupied band scores as one on
        its face.
    occupied_threshold : float
        Cells with occupancy ``>= occupied_threshold`` are obstacles: they stop
        the rays of the beam model and are the sources of the likelihood field.
    free_threshold : float
        Cells with occupancy ``<= free_threshold`` are free space: the initial
        particles and Augmented MCL's random particles are drawn there.
    reject_unknown : bool
        Particles outside free space (in walls, unknown cells or cells whose
        occupancy exceeds `free_threshold`) get zero weight.
    mode_particles : int
        Mode-preserving resampling (:func:`augmented_mcl_step` only; ``0``
        turns it off): when the step resamples, every mode of the belief
        (a connected cluster of particles, 1 m cells) whose posterior mass is
        at least `mode_floor` keeps at least this many particles, which share
        its mass, so a mode that a few unusual scans make improbable is not
        wiped out by resampling and can win again when the scans fit it. With
        one mode this is plain low-variance resampling. The default, 100, is
        about Table 8.4's KLD bound (``epsilon = 0.05``, ``delta = 0.01``)
        for a mode that occupies three or four 0.5 m x 0.5 m x 10 degree bins
        (92 and 114 particles), the size of a converged cloud. At most half of
        the particles go to these minimum shares (the heaviest modes first:
        fifty modes with the defaults), because a corridor whose doors repeat
        every few metres has dozens of look-alike places; on Wean Hall log 2
        (with ``likelihood_exponent = 0.2``), keeping ten modes found the
        robot in 14 of 20 seeds, 25 modes in 19, 50 in 20
        (``benchmarks/mcl_success.py``). That budget was chosen on
        log 2; over the broader study of ``benchmarks/mcl_study.py``
        (simulated drives and many start offsets on both logs) turning
        mode-preserving resampling off made no measurable difference.
    mode_floor : float
        Modes with posterior mass below this are resampled as usual (they get
        ``M W_c`` particles, usually none): one in a million.
    estimate_hysteresis : float
        The estimate stays with the mode of the previous estimate (the
        particles within 1.5 m of it, after two mean-shift steps) as long as
        that mode's mass is at least ``1 / estimate_hysteresis`` of the
        heaviest mode's; otherwise it moves to the heaviest mode. ``1`` always
        takes the heaviest. Measured on every trial of
        ``benchmarks/mcl_study.py`` (``--configs "estimate hysteresis 2"``),
        hysteresis lost strict successes on both sets: 2 gave 80 of 100
        simulated drives and 5 of 20 log starts against the default's 85 and
        6; an estimate that stays with a mode the scans have
        left is wrong for longer than one that follows the heaviest.
    estimate_radius : float
        The estimate is moved from the heaviest mode's mean to the densest
        place of the mode by mean-shift steps over the particles within this
        distance [m] (``0``: the mode's mean). A mode stretched along a
        corridor has its mean where the particles are sparse; its densest
        place is where the scans fit best.
    init_candidates : int
        Global localization starts from the first scan (:func:`mcl_initialize`
        with ``scan``): this many poses uniform over the free space are weighted
        by the first scan's (tempered) likelihood and ``n_particles`` are drawn
        from them, so the particles start where the scan fits the map instead
        of one per 0.04 m^2 everywhere. ``0`` starts from ``n_particles``
        uniform poses (Table 8.2).
    beam_skip_distance, beam_skip_share, beam_skip_limit : float
        Beam skipping (likelihood field only; ``beam_skip_share = 0`` turns it
        off). A beam whose endpoint lies within `beam_skip_distance` [m] of an
        obstacle for less than `beam_skip_share` of the predicted belief's
        mass is left out of this scan's likelihood for every particle (and for
        sensor resetting's candidates): no part of the belief explains it, so
        it is most likely a change of the world the map does not show (a door
        left open, a person, a box), and the likelihood field would charge the
        right pose ``log(w_rand / z_max)`` for it at every scan until the
        robot has passed. Unless more than `beam_skip_limit` of the scan's
        used beams would be left out: then the scan contradicts the belief,
        not the map (a kidnapping, a wrong convergence), and every beam counts.
        This is the outlier rejection of Sec. 8.4 (a measurement that the
        belief, averaged over its particles, attributes to something unmapped
        is not used) in the form of ROS amcl's beam skipping, with the
        particles weighted by the belief. It keeps a filter that is right from
        being handed to a look-alike place that explains the unmapped
        readings (on Wean Hall log 2, a place some 10 m away, heading the
        other way, explains openings the map shows closed); it also keeps a
        filter that converged to a wrong place from hearing the beams only the
        right place explains, until more than `beam_skip_limit` of them
        disagree. It is off by default:
        with ``beam_skip_share = 0.05`` the filter started at the truth kept
        the right place on every log window of ``benchmarks/mcl_study.py``,
        but from a global start it was confidently wrong at more updates on
        most sets (the 150-update log windows, the whole of log 2, the
        simulated sets of ``benchmarks/mcl_holdout.py``), for a few more
        strict successes; chapter 5 shows both effects. Use it to track from
        a known start in a building whose map is out of date.
    augmented : AugmentedParams
        Used by :func:`augmented_mcl_step` (the default variant of
        :func:`run_mcl`).
    kld : KLDParams
        Used by :func:`kld_mcl_step`.
    """

    n_particles: int = 10_000
    alpha: tuple[float, float, float, float] = (0.05, 0.005, 0.05, 0.005)
    model: str = "likelihood_field"
    ray_cache_angles: int = 360
    beam_step: int = 10
    z_max: float = 81.83
    sigma_hit: float = 0.3
    lambda_short: float = 0.1
    w_hit: float = 0.85
    w_short: float = 0.05
    w_max: float = 0.05
    w_rand: float = 0.05
    max_dist: float = 2.0
    likelihood_exponent: float = 0.1
    resample_threshold: float = 0.5
    min_translation: float = 0.2
    min_rotation: float = 0.2
    sensor_offset: float = 0.25
    range_bias: float = 0.0
    occupied_threshold: float = 0.9
    free_threshold: float = 0.1
    reject_unknown: bool = True
    mode_particles: int = 100
    mode_floor: float = 1e-6
    estimate_hysteresis: float = 1.0
    estimate_radius: float = 0.5
    init_candidates: int = 200_000
    beam_skip_distance: float = 0.5
    beam_skip_share: float = 0.0
    beam_skip_limit: float = 0.5
    augmented: AugmentedParams = field(default_factory=AugmentedParams)
    kld: KLDParams = field(default_factory=KLDParams)

    def __post_init__(self):
        as_index(self.n_particles, "n_particles", lower=1)
        a = as_array(self.alpha, "alpha", (4,))
        if np.any(a < 0):
            raise ValueError(f"alpha must be non-negative, got {tuple(a)}")
        if self.model not in _MODELS:
            raise ValueError(f"model must be one of {_MODELS}, got {self.model!r}")
        as_index(self.beam_step, "beam_step", lower=1)
        as_index(self.ray_cache_angles, "ray_cache_angles")
        for name in ("z_max", "sigma_hit", "lambda_short", "max_dist", "likelihood_exponent"):
            as_scalar(getattr(self, name), name, positive=True)
        for name in ("w_hit", "w_short", "w_max", "w_rand", "min_translation", "min_rotation", "sensor_offset"):
            as_scalar(getattr(self, name), name, nonnegative=True)
        as_scalar(self.range_bias, "range_bias")
        ft = as_scalar(self.free_threshold, "free_threshold", nonnegative=True)
        ot = as_scalar(self.occupied_threshold, "occupied_threshold", positive=True)
        if not ft < ot <= 1.0:
            raise ValueError(f"thresholds must satisfy 0 <= free_threshold < occupied_threshold <= 1, got {ft}, {ot}")
        thr = as_scalar(self.resample_threshold, "resample_threshold", nonnegative=True)
        if thr > 1.0:
            raise ValueError(f"resample_threshold must be in [0, 1], got {thr}")
        as_index(self.mode_particles, "mode_particles")
        as_index(self.init_candidates, "init_candidates")
        as_scalar(self.beam_skip_distance, "beam_skip_distance", positive=True)
        for name in ("beam_skip_share", "beam_skip_limit"):
            v = as_scalar(getattr(self, name), name, nonnegative=True)
            if v > 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {v}")
        if self.beam_skip_share > 0 and self.model != "likelihood_field":
            raise ValueError(f"beam_skip_share must be 0 with model={self.model!r}: beam skipping works with the "
                             "likelihood field (the beam model explains unmapped objects by its short readings, w_short)")
        as_scalar(self.estimate_radius, "estimate_radius", nonnegative=True)
        h = as_scalar(self.estimate_hysteresis, "estimate_hysteresis", positive=True)
        if h < 1.0:
            raise ValueError(f"estimate_hysteresis must be >= 1, got {h}")
        mf = as_scalar(self.mode_floor, "mode_floor", positive=True)
        if mf >= 1.0:
            raise ValueError(f"mode_floor must be in (0, 1), got {mf}")
        if not isinstance(self.augmented, AugmentedParams):
            raise TypeError(f"augmented must be an AugmentedParams, got {type(self.augmented).__name__}")
        if not isinstance(self.kld, KLDParams):
            raise TypeError(f"kld must be a KLDParams, got {type(self.kld).__name__}")


@dataclass(frozen=True)
class MCLModel:
    """Everything a run keeps fixed: the map, its likelihood field and the parameters.

    Build it with :func:`prepare_mcl` (the likelihood field is computed once).

    Attributes
    ----------
    grid : OccupancyGrid
        The map.
    field : LikelihoodField
        Distance-to-nearest-obstacle table of `grid` (used by the likelihood
        field and by :func:`endpoint_distances`).
    params : MCLParams
        Filter parameters.
    rays : RangeTable or None
        The beam model's pre-cached ray casting (``None`` for the likelihood
        field, or when ``params.ray_cache_angles == 0``).
    """

    grid: OccupancyGrid
    field: object
    params: MCLParams
    rays: object = None


@dataclass(frozen=True)
class MCLState:
    """A particle set.

    Attributes
    ----------
    poses : ndarray, shape (M, 3)
        Particles ``[x, y, theta]``.
    log_weights : ndarray, shape (M,)
        Normalised log-weights (``logsumexp(log_weights) == 0``).
    log_w_slow, log_w_fast : float
        Logarithms of the long- and short-term averages of the measurement
        likelihood (Augmented MCL, Table 8.3); ``-inf`` until the first update,
        which sets both to its average likelihood.
    estimate : ndarray, shape (3,), optional
        The last step's pose estimate (``None`` before the first step); the
        next step's estimate keeps to its mode (``estimate_hysteresis``).
    """

    poses: np.ndarray
    log_weights: np.ndarray
    log_w_slow: float = -np.inf
    log_w_fast: float = -np.inf
    estimate: np.ndarray | None = None

    @property
    def weights(self):
        """Normalised weights, shape (M,)."""
        return np.exp(self.log_weights)

    @property
    def w_slow(self):
        """Long-term average likelihood ``exp(log_w_slow)``."""
        return float(np.exp(self.log_w_slow))

    @property
    def w_fast(self):
        """Short-term average likelihood ``exp(log_w_fast)``."""
        return float(np.exp(self.log_w_fast))

    def __len__(self):
        return self.poses.shape[0]


class MCLStepInfo(NamedTuple):
    """What one filter step did.

    Attributes
    ----------
    ess : float
        Effective sample size of the weights after the measurement update.
    n_particles : int
        Number of particles after the step.
    resampled : bool
        Whether the step resampled.
    n_injected : int
        Random particles added (Augmented MCL).
    log_w_avg : float
        Log of the average measurement likelihood under the predicted belief,
        ``log sum_m w_{t-1}^[m] p(z_t | x_t^[m], m)^tau`` (Table 8.3 with
        the filter's tempered likelihood); ``-inf`` if no particle is in free
        space.
    mean : ndarray, shape (3,)
        Weighted mean pose of the particles after the measurement update,
        before resampling and injection (the step's estimate).
    spread : float
        Weighted RMS distance of those particles from `mean` [m].
    heading_spread : float
        Circular standard deviation of their headings [rad].
    estimate : ndarray, shape (3,)
        Weighted mean of the heaviest cluster of those particles (see
        :func:`particle_estimate`): the pose estimate, which stays in one place
        when the particles form several clusters.
    mode_mass : float
        Posterior mass of the heaviest mode (the particles within 1.5 m of
        the estimate): the filter's own measure of how sure it is.
    n_modes : int
        Number of modes holding at least 1 % of the mass (found greedily:
        the heaviest mode, then the heaviest among the remaining particles,
        ...; at most 8).
    confidence : float
        Posterior mass within 0.5 m of the estimate: the filter's probability
        that its estimate is within 0.5 m of the true pose. A mode stretched
        over metres can hold all the mass while the estimate is still
        uncertain by more than 0.5 m; this measures the claim at the scale
        of the estimate.
    """

    ess: float
    n_particles: int
    resampled: bool
    n_injected: int
    log_w_avg: float
    mean: np.ndarray
    spread: float
    heading_spread: float
    estimate: np.ndarray
    mode_mass: float = 1.0
    n_modes: int = 1
    confidence: float = 1.0


@dataclass(frozen=True)
class MCLResult:
    """Per-step statistics of a run of :func:`run_mcl` (``S`` filter steps).

    Attributes
    ----------
    scan_index : ndarray of int, shape (S,)
        Index into the log's scans of every filter step.
    t : ndarray, shape (S,)
        Time stamp of every step [s] (scan index if no times were given).
    mean : ndarray, shape (S, 3)
        Weighted mean pose (circular mean heading) after the update.
    estimate : ndarray, shape (S, 3)
        Weighted mean of the heaviest cluster after the update (the pose
        estimate, :func:`particle_estimate`).
    spread : ndarray, shape (S,)
        Weighted RMS distance of the particles from the mean position [m].
    heading_spread : ndarray, shape (S,)
        Weighted circular standard deviation of the headings [rad].
    ess : ndarray, shape (S,)
        Effective sample size after the measurement update.
    n_particles : ndarray of int, shape (S,)
        Number of particles.
    n_injected : ndarray of int, shape (S,)
        Random particles injected (Augmented MCL).
    log_w_avg : ndarray, shape (S,)
        Log of the average (tempered) measurement likelihood of every step.
    log_w_slow, log_w_fast : ndarray, shape (S,)
        Logs of the Augmented MCL averages after every step.
    snapshot_steps : ndarray of int, shape (N,)
        Steps at which particles were stored.
    snapshots : list of MCLState
        Particle sets after those steps (usable as ``init`` of another run).
    final : MCLState
        Particle set after the last step.
    runtime : float
        Wall time of the filter loop and of the initial particle set [s].
    mode_mass : ndarray, shape (S,)
        Mass of the heaviest mode after every update (:class:`MCLStepInfo`).
    n_modes : ndarray of int, shape (S,)
        Number of modes holding at least 1 % of the mass.
    confidence : ndarray, shape (S,)
        Posterior mass within 0.5 m of the estimate after every update
        (:class:`MCLStepInfo`).
    """

    scan_index: np.ndarray
    t: np.ndarray
    mean: np.ndarray
    estimate: np.ndarray
    spread: np.ndarray
    heading_spread: np.ndarray
    ess: np.ndarray
    n_particles: np.ndarray
    n_injected: np.ndarray
    log_w_avg: np.ndarray
    log_w_slow: np.ndarray
    log_w_fast: np.ndarray
    snapshot_steps: np.ndarray
    snapshots: list
    final: MCLState
    runtime: float
    mode_mass: np.ndarray = None
    n_modes: np.ndarray = None
    confidence: np.ndarray = None

    def __len__(self):
        return self.scan_index.shape[0]

    def ambiguity(self):
        """Per update: mass of the heaviest mode and number of modes (>= 1 % of the mass)."""
        return self.mode_mass, self.n_modes


# --------------------------------------------------------------------------- checks
def _check_model(model):
    return check_type(model, MCLModel, "model", "from prepare_mcl")


def _check_state(state):
    return check_type(state, MCLState, "state", "from mcl_initialize")


# --------------------------------------------------------------------------- set-up
def prepare_mcl(grid, params=None):
    """Bundle a map and parameters, computing the likelihood field once.

    Parameters
    ----------
    grid : OccupancyGrid
        The map.
    params : MCLParams, optional
        Filter parameters (defaults if omitted).

    Returns
    -------
    MCLModel
        ``(grid, field, params, rays)``, with ``field = likelihood_field(grid,
        max_dist=params.max_dist, threshold=params.occupied_threshold)``; for
        the beam model, ``rays`` is an empty
        :class:`~slamlib.sensors.RangeTable` over the free space widened by
        the sensor offset (where the particles' sensors can be).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3 (the likelihood field is
    precomputed once per map), Sec. 6.3.4 (pre-cached ray casting).
    """
    if not isinstance(grid, maps.OccupancyGrid):
        raise TypeError(f"grid must be an OccupancyGrid, got {type(grid).__name__}")
    params = MCLParams() if params is None else params
    if not isinstance(params, MCLParams):
        raise TypeError(f"params must be an MCLParams, got {type(params).__name__}")
    lf = sensors.likelihood_field(grid, max_dist=params.max_dist, threshold=params.occupied_threshold)
    rays = None
    if params.model == "beam" and params.ray_cache_angles > 0:
        reach = int(np.ceil(params.sensor_offset / grid.resolution)) + 1
        disk = np.hypot(*np.mgrid[-reach:reach + 1, -reach:reach + 1]) <= reach
        region = ndimage.binary_dilation(grid.free_mask(params.free_threshold), structure=disk)
        region &= ~grid.occupied_mask(params.occupied_threshold)
        rays = sensors.range_table(grid, max_range=params.z_max, threshold=params.occupied_threshold,
                                   n_angles=params.ray_cache_angles, region=region)
    return MCLModel(grid=grid, field=lf, params=params, rays=rays)


def odometry_steps(odom_poses, *, min_translation=0.2, min_rotation=0.2, turn_in_place=0.01):
    """Turn a log's odometry poses (one per scan) into filter steps.

    The first scan is always used, with a zero control. A later scan is used
    once the odometry has moved at least `min_translation` or turned at least
    `min_rotation` since the last used scan; the skipped scans' motion is
    merged into the next step's control, so no odometry is lost.

    A step that translates less than `turn_in_place` is a turn in place: its
    control is ``[0, trans, rot]`` with the whole turn in ``rot2`` (its few
    millimetres of translation are then applied straight ahead). Table 5.5
    would take ``rot1`` from the direction of the few millimetres of wheel
    slip (a slip of 2 mm backwards makes ``rot1`` and ``rot2`` two opposite
    turns of nearly 180 degrees), and the noise of Table 5.6, which grows with
    ``rot1**2 + rot2**2``, would then scatter the headings by tens of degrees
    for a turn of a few. ROS ``amcl`` does the same below 1 cm.

    Parameters
    ----------
    odom_poses : ndarray, shape (L, 3)
        Odometry pose of the robot at every scan (the log's own frame).
    min_translation : float
        Minimum distance [m] between updates.
    min_rotation : float
        Minimum absolute turn [rad] between updates.
    turn_in_place : float, keyword-only
        Translation [m] below which a step counts as a turn in place (``0``
        keeps Table 5.5's increments for every step).

    Returns
    -------
    index : ndarray of int, shape (S,)
        Indices of the scans to filter, increasing, starting with 0.
    u : ndarray, shape (S, 3)
        Odometry control ``[rot1, trans, rot2]`` from the previous used scan
        to each used scan (zeros for the first).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 5.4 (odometry as a control) and
    Table 5.5 lines 2-4 (the increments).
    """
    odom = as_array(odom_poses, "odom_poses", (None, 3))
    if odom.shape[0] == 0:
        raise ValueError("odom_poses must hold at least one pose")
    d_min = as_scalar(min_translation, "min_translation", nonnegative=True)
    a_min = as_scalar(min_rotation, "min_rotation", nonnegative=True)
    d_turn = as_scalar(turn_in_place, "turn_in_place", nonnegative=True)
    index = [0]
    last = odom[0]
    for i in range(1, odom.shape[0]):  # a loop over scans, not over particles
        moved = np.hypot(odom[i, 0] - last[0], odom[i, 1] - last[1])
        turned = abs(wrap_angle(odom[i, 2] - last[2]))
        if moved >= d_min and moved > 0 or turned >= a_min and turned > 0:
            index.append(i)
            last = odom[i]
    index = np.asarray(index, dtype=np.intp)
    u = np.zeros((index.size, 3))
    if index.size > 1:
        u[1:] = odometry_from_poses(odom[index[:-1]], odom[index[1:]])
        spin = u[:, 1] < d_turn
        spin[0] = False
        # a turn in place: the whole turn in rot2, none taken from the direction of the slip
        u[spin, 2] = wrap_angle(odom[index[spin], 2] - odom[index[np.flatnonzero(spin) - 1], 2])
        u[spin, 0] = 0.0
    return index, u


def mcl_initialize(model, n=None, *, rng, poses=None, scan=None):
    """A particle set spread uniformly over the map's free space (global localization).

    Parameters
    ----------
    model : MCLModel
        Map and parameters.
    n : int, optional
        Number of particles; ``model.params.n_particles`` if omitted.
    rng : numpy.random.Generator
        Source of randomness (used by ``sample_free_poses``).
    poses : ndarray, shape (M, 3), optional
        Start from these particles instead (position tracking).
    scan : tuple (ranges, angles), optional
        The first scan (global localization only, with
        ``params.init_candidates > 0``): ``init_candidates`` uniform free
        poses are weighted by this scan's tempered likelihood
        ``q(x) ~ p(z | x, m)^tau`` and `n` particles are drawn from them
        (low-variance). The particles are an importance sample of the uniform
        prior with proposal ``q``: their log-weights are ``-tau log p(z | x, m)``
        (normalised), so the first filter update, which multiplies by
        ``p(z | x, m)^tau`` at the same poses, leaves them equally weighted.
        Far more candidates than particles are affordable (one scan, few
        beams), so many more particles start near the true pose.

    Returns
    -------
    MCLState
        Equal weights (importance weights with `scan`), ``w_slow = w_fast = 0``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 8.3 (global localization starts from a
    uniform prior).
    """
    model = _check_model(model)
    check_rng(rng)
    if poses is None:
        n = model.params.n_particles if n is None else as_index(n, "n", lower=1)
        p = model.params
        if scan is not None and p.init_candidates > 0:
            ranges, angles = as_scan(*scan)
            z, a = _subsample(ranges, angles, p)
            cand = maps.sample_free_poses(model.grid, p.init_candidates, rng=rng, threshold=p.free_threshold)
            tll = p.likelihood_exponent * _scan_loglik(model, cand, z, a)
            if np.any(np.isfinite(tll)):
                q = _safe_normalize(tll)
                w = np.exp(q)
                # n of the candidates by low-variance resampling (Table 4.4 with n draws)
                idx = particle._low_variance_indices(w / w.sum(), rng.uniform(0.0, 1.0 / n), n)
                return MCLState(poses=cand[idx], log_weights=_safe_normalize(-tll[idx]))
        poses = maps.sample_free_poses(model.grid, n, rng=rng, threshold=p.free_threshold)
    else:
        poses = as_array(poses, "poses", (None, 3))
        if poses.shape[0] == 0:
            raise ValueError("poses must hold at least one particle")
        poses[:, 2] = wrap_angle(poses[:, 2])
    m = poses.shape[0]
    return MCLState(poses=poses, log_weights=np.full(m, -np.log(m)))


# --------------------------------------------------------------------------- measurement
def _subsample(ranges, angles, params):
    z = np.minimum(ranges[:: params.beam_step], params.z_max)
    return z, angles[:: params.beam_step]


def _field_terms(model, poses, z, a, per_beam=False):
    """The likelihood field's log-likelihood of every particle: summed, shape (M,), or per beam, (M, K)."""
    p = model.params
    return sensors.likelihood_field_log_likelihood(model.field, poses, z, a, z_max=p.z_max, sigma_hit=p.sigma_hit,
                                                   w_hit=p.w_hit, w_rand=p.w_rand, sensor_offset=p.sensor_offset,
                                                   per_beam=per_beam)


def _scan_loglik(model, poses, z, a):
    """Summed log-likelihood over the used beams, shape (M,)."""
    p = model.params
    if p.model == "likelihood_field":
        ll = _field_terms(model, poses, z, a)
    else:
        if model.rays is not None:
            z_star = sensors._biased_ranges(model.rays.ranges(poses, a, sensor_offset=p.sensor_offset),
                                           p.range_bias, p.z_max)
        else:
            z_star = sensors.ray_cast(model.grid, poses, a, p.z_max, sensor_offset=p.sensor_offset,
                                      threshold=p.occupied_threshold, range_bias=p.range_bias)
        ll = sensors.beam_range_finder_log_likelihood(z, z_star, z_max=p.z_max, sigma_hit=p.sigma_hit,
                                              lambda_short=p.lambda_short, w_hit=p.w_hit, w_short=p.w_short,
                                              w_max=p.w_max, w_rand=p.w_rand)
        ll = np.sum(ll, axis=-1) if np.ndim(ll) == 2 else ll
    return _unknown_rejected(model, poses, ll)


def _unknown_rejected(model, poses, ll):
    """``ll`` with ``-inf`` for the particles outside free space (``params.reject_unknown``)."""
    p = model.params
    if p.reject_unknown:
        ll = np.where(model.grid.is_free(poses[:, :2], p.free_threshold), ll, -np.inf)
    return ll


def _kept_beams(params, log_w, terms, z):
    """The beams of a scan that the predicted belief explains, shape (K,) bool (beam skipping).

    ``terms`` are the likelihood field's per-beam log-likelihoods ``(M, K)`` of the predicted particles,
    ``log_w`` their weights. A beam whose endpoint lies within ``params.beam_skip_distance`` of an
    obstacle for less than ``params.beam_skip_share`` of the belief's mass is left out for every particle,
    unless more than ``params.beam_skip_limit`` of the used beams would be (then the scan contradicts the
    belief, not the map, and every beam is kept).
    """
    keep = np.ones(z.size, dtype=bool)
    used = z < params.z_max
    if params.beam_skip_share <= 0.0 or not np.any(used):
        return keep
    # endpoint closer than d to an obstacle  <=>  its term exceeds the term at distance d (decreasing in the distance)
    t_d = sensors._field_beam_log_likelihood(params.beam_skip_distance, params.sigma_hit, params.w_hit, params.w_rand,
                                             params.z_max)
    w = np.exp(log_w - logsumexp(log_w))
    explained = w @ (terms[:, used] > t_d)  # the belief's mass whose endpoint of beam k is near an obstacle
    out = explained < params.beam_skip_share
    if np.count_nonzero(out) > params.beam_skip_limit * np.count_nonzero(used):
        return keep
    keep[np.flatnonzero(used)[out]] = False
    return keep


def _weigh(model, poses, log_w, z, a):
    """Scan log-likelihood of the predicted particles ``(M,)`` after beam skipping, and the beams kept."""
    p = model.params
    if p.model != "likelihood_field" or p.beam_skip_share <= 0.0:
        return _scan_loglik(model, poses, z, a), z, a
    terms = _field_terms(model, poses, z, a, per_beam=True)
    keep = _kept_beams(p, log_w, terms, z)
    return _unknown_rejected(model, poses, terms[:, keep].sum(axis=1)), z[keep], a[keep]


def scan_log_likelihood(model, poses, ranges, angles):
    """Log-likelihood ``log p(z | x, m)`` of one laser scan for every particle.

    Parameters
    ----------
    model : MCLModel
        Map, likelihood field and parameters (``model``, ``beam_step``,
        ``z_max``, mixture weights).
    poses : ndarray, shape (M, 3)
        Particles.
    ranges : ndarray, shape (K,)
        The full scan [m]; every ``beam_step``-th beam is used and ranges are
        clipped at ``z_max``.
    angles : ndarray, shape (K,)
        Beam angles in the laser frame [rad].

    Returns
    -------
    ndarray, shape (M,)
        Sum over the used beams of the per-beam log-likelihood (beams treated
        as independent, Eq. 6.2); ``-inf`` for particles outside free space when
        ``reject_unknown``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Eq. 6.2, Table 6.1 (beam model), Table 6.3
    (likelihood field).
    """
    model = _check_model(model)
    poses = as_array(poses, "poses", (None, 3))
    ranges, angles = as_scan(ranges, angles)
    z, a = _subsample(ranges, angles, model.params)
    return _scan_loglik(model, poses, z, a)


# --------------------------------------------------------------------------- filter steps
def _safe_normalize(log_w):
    """Normalised log-weights; uniform when every particle has zero weight."""
    if not np.any(np.isfinite(log_w)):
        return np.full(log_w.shape, -np.log(log_w.size))
    return log_w - logsumexp(log_w)


def _predict_and_weight(state, u, ranges, angles, model, rng):
    p = model.params
    # x_t^[m] ~ p(x_t | u_t, x_{t-1}^[m])  (Table 8.2 line 4)
    poses = sample_motion_model_odometry(state.poses, u, p.alpha, rng=rng)
    z, a = _subsample(ranges, angles, p)
    ll, z, a = _weigh(model, poses, state.log_weights, z, a)
    return poses, ll, z, a


def _update(state, poses, ll, model):
    """Weights after the measurement, and log of the average likelihood under the predicted belief."""
    tll = model.params.likelihood_exponent * ll
    # w_t^[m] = p(z_t | x_t^[m], m)^tau  (Table 8.2 line 5, tempered)
    log_w = _safe_normalize(state.log_weights + tll)
    # w_avg = sum_m w_{t-1}^[m] p(z_t | x_t^[m], m)^tau  (Table 8.3, in log space)
    finite = np.isfinite(tll)
    log_w_avg = float(logsumexp(state.log_weights[finite] + tll[finite])) if np.any(finite) else -np.inf
    return log_w, log_w_avg


def _averages(state, log_w_avg, aug):
    """Log of w_slow and w_fast after this update (exponential averages kept in log space)."""
    if not np.isfinite(log_w_avg):
        return state.log_w_slow, state.log_w_fast  # nothing measured: keep the averages
    if not (np.isfinite(state.log_w_slow) and np.isfinite(state.log_w_fast)):
        if aug.average_start == "zero":
            # Table 8.3: w_slow = w_fast = 0 before the first update, so w += alpha (w_avg - 0)
            ls = np.log(aug.alpha_slow) + log_w_avg if aug.alpha_slow > 0 else -np.inf
            lf = np.log(aug.alpha_fast) + log_w_avg if aug.alpha_fast > 0 else -np.inf
            return float(ls), float(lf)
        # first update: start both averages at w_avg, so that the test works from the first update
        return log_w_avg, log_w_avg
    # w_slow += alpha_slow (w_avg - w_slow); w_fast += alpha_fast (w_avg - w_fast)  (Table 8.3)
    return _log_mix(state.log_w_slow, log_w_avg, aug.alpha_slow), _log_mix(state.log_w_fast, log_w_avg, aug.alpha_fast)


def _log_mix(log_a, log_b, alpha):
    """log((1 - alpha) a + alpha b) from log a and log b, without underflow."""
    if alpha <= 0.0:
        return log_a
    if alpha >= 1.0:
        return log_b
    return float(np.logaddexp(np.log1p(-alpha) + log_a, np.log(alpha) + log_b))


def _injection_probability(log_w_slow, log_w_fast):
    """max(0, 1 - w_fast / w_slow)  (Table 8.3)."""
    if not (np.isfinite(log_w_slow) and np.isfinite(log_w_fast)):
        return 0.0
    return float(max(0.0, -np.expm1(min(log_w_fast - log_w_slow, 0.0))))


def _resample_mask(log_w, threshold):
    w = np.exp(log_w)
    ess = float(particle.effective_sample_size(w))
    return w, ess, ess < threshold * w.size


def _clusters(xy, cell):
    """Label every particle with its cluster: 8-connected blocks of occupied ``cell`` x ``cell`` position cells."""
    ij = np.floor(xy / cell).astype(np.int64)
    ij -= ij.min(axis=0) - 1  # one empty cell of margin
    shape = tuple(ij.max(axis=0) + 2)
    occupied = np.zeros(shape, dtype=bool)
    occupied[ij[:, 0], ij[:, 1]] = True
    labels, n = ndimage.label(occupied, structure=np.ones((3, 3), dtype=bool))
    return labels[ij[:, 0], ij[:, 1]] - 1, n


def _mode_preserving_resample(poses, w, rng, n_keep, floor, cell=_CLUSTER_CELL):
    """Low-variance resampling within each mode of the belief; modes keep their mass and at least `n_keep` particles.

    Plain resampling gives a mode ``M W_c`` particles: a mode whose mass falls
    to ``1e-4`` for a few updates (an unusual scan, a changed piece of the
    map) loses every particle, and nothing can bring it back. Here every mode
    (cluster of particles) with mass ``W_c >= floor`` gets ``n_keep`` particles
    plus its share of the rest (at most ``_MODE_BUDGET * M // n_keep`` modes,
    the heaviest); its particles are drawn by low-variance
    resampling from its own weights and share its mass ``W_c`` equally, so
    the weighted particle set still represents the same posterior. With one
    mode this is plain low-variance resampling.

    Returns the new indices ``(M,)`` and log-weights ``(M,)``.
    """
    M = w.size
    labels, C = _clusters(poses[:, :2], cell)
    W = np.bincount(labels, weights=w, minlength=C)
    kept = np.flatnonzero(W >= floor)
    n_modes = max(1, int(_MODE_BUDGET * M) // max(n_keep, 1))  # at most half of the set on minimum shares
    kept = kept[np.argsort(-W[kept], kind="stable")][:n_modes]  # the heaviest modes first
    if kept.size <= 1:
        return particle._low_variance_indices(w / w.sum(), rng.uniform(0.0, 1.0 / M), M), np.full(M, -np.log(M))
    Wk = W[kept] / W[kept].sum()  # lighter modes are dropped; the kept ones are renormalised
    share = (M - n_keep * kept.size) * Wk
    n = n_keep + np.floor(share).astype(np.intp)
    rest = M - n.sum()
    n[np.argsort(-(share - np.floor(share)), kind="stable")[:rest]] += 1  # largest remainders
    # group the particles by mode: a cumulative weight that runs from 0 to 1 inside every kept mode
    rank = np.full(C, -1, dtype=np.intp)
    rank[kept] = np.arange(kept.size)
    r_of = rank[labels]
    member = np.flatnonzero(r_of >= 0)
    order = member[np.argsort(r_of[member], kind="stable")]
    g = r_of[order]
    wg = w[order] / W[kept][g]
    size = np.bincount(g, minlength=kept.size)  # particles of every kept mode
    start = np.r_[0, np.cumsum(size)[:-1]]  # where each mode's block begins in `order`
    c = np.cumsum(wg) - np.repeat(np.r_[0.0, np.cumsum(np.bincount(g, weights=wg, minlength=kept.size))[:-1]], size)
    # pointers r_c + k / n_c of every mode (Table 4.4 within the mode)
    mode_of_ptr = np.repeat(np.arange(kept.size), n)
    k = np.arange(M) - np.repeat(np.r_[0, np.cumsum(n)[:-1]], n)
    ptr = rng.uniform(0.0, 1.0, size=kept.size)[mode_of_ptr] / n[mode_of_ptr] + k / n[mode_of_ptr]
    # search inside each mode's block: add twice the mode index so blocks do not overlap
    pos = np.searchsorted(c + g * 2.0, np.minimum(ptr, 1.0 - 1e-12) + mode_of_ptr * 2.0, side="left")
    pos = np.minimum(pos, (start + size - 1)[mode_of_ptr])
    idx = order[pos]
    log_w = np.log(Wk[mode_of_ptr]) - np.log(n[mode_of_ptr])
    return idx, log_w


def _sensor_component(model, z, a, rng):
    """Uniform poses over the free space weighted by the scan: the candidates and their log-weights.

    Returns the candidates, their normalised log-weights ``tau log p(z | x, m)`` and
    ``log Z_U``, the log of the average tempered likelihood over the free space (a
    Monte Carlo estimate of ``integral p(z | x, m)^tau U(x) dx``).
    """
    p = model.params
    cand = maps.sample_free_poses(model.grid, p.augmented.candidates, rng=rng, threshold=p.free_threshold)
    tll = p.likelihood_exponent * _scan_loglik(model, cand, z, a)
    if not np.any(np.isfinite(tll)):
        return cand, np.full(cand.shape[0], -np.log(cand.shape[0])), -np.inf
    log_z = float(logsumexp(tll) - np.log(tll.size))
    return cand, tll - logsumexp(tll), log_z


def _injected_fraction(p_inject, log_w_avg, log_z_u):
    """Posterior mass of the uniform component of the prior (1 - p) bel + p U after weighting by the scan.

    ``p Z_U / (p Z_U + (1 - p) w_avg)``: the belief's particles carry ``(1 - p) w_avg``
    (``w_avg`` is their weighted average likelihood), the uniform component ``p Z_U``.
    """
    if p_inject <= 0.0 or not np.isfinite(log_z_u):
        return 0.0
    if not np.isfinite(log_w_avg):
        return 1.0  # no particle of the belief explains the scan at all
    log_u = np.log(p_inject) + log_z_u
    log_b = np.log1p(-p_inject) + log_w_avg if p_inject < 1.0 else -np.inf
    return float(np.exp(log_u - np.logaddexp(log_u, log_b)))


def _check_step_args(state, u, ranges, angles, model, rng):
    state = _check_state(state)
    model = _check_model(model)
    u = as_array(u, "u", (3,))
    ranges, angles = as_scan(ranges, angles)
    check_rng(rng)
    return state, u, ranges, angles, model


def mcl_step(state, u, ranges, angles, model, *, rng):
    """One step of Monte Carlo localization (Table 8.2).

    Parameters
    ----------
    state : MCLState
        Particles and log-weights at ``t - 1``.
    u : ndarray, shape (3,)
        Odometry control ``[rot1, trans, rot2]`` since the previous step.
    ranges : ndarray, shape (K,)
        Laser scan at ``t`` [m].
    angles : ndarray, shape (K,)
        Beam angles in the laser frame [rad].
    model : MCLModel
        Map, likelihood field and parameters.
    rng : numpy.random.Generator
        Source of randomness: the motion samples, then (if the step resamples)
        the one uniform draw of low-variance resampling.

    Returns
    -------
    state : MCLState
        Particles at ``t``: equally weighted if the step resampled, else
        weighted. ``w_slow`` and ``w_fast`` are updated as in Table 8.3 (but
        not used), so that Augmented MCL can take over from this state.
    info : MCLStepInfo
        ESS, particle count, whether it resampled.

    Notes
    -----
    Table 8.2 resamples at every step (``resample_threshold = 1``); resampling
    only when the effective sample size is low keeps more diversity
    (Sec. 4.3.4).

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.2; low-variance resampling Table 4.4.
    """
    state, u, ranges, angles, model = _check_step_args(state, u, ranges, angles, model, rng)
    poses, ll, _, _ = _predict_and_weight(state, u, ranges, angles, model, rng)
    log_w, log_w_avg = _update(state, poses, ll, model)
    summary = _summary(poses, log_w, state.estimate, model.params.estimate_hysteresis, model.params.estimate_radius)
    w, ess, do = _resample_mask(log_w, model.params.resample_threshold)
    if do:
        # draw i with probability proportional to w_t^[i]  (Table 8.2 lines 8-11)
        idx = particle.low_variance_resample(w, rng=rng)
        poses, log_w = poses[idx], np.full(idx.size, -np.log(idx.size))
    log_slow, log_fast = _averages(state, log_w_avg, model.params.augmented)  # tracked, not used
    new = MCLState(poses=poses, log_weights=log_w, log_w_slow=log_slow, log_w_fast=log_fast, estimate=summary[3])
    return new, MCLStepInfo(ess, poses.shape[0], bool(do), 0, log_w_avg, *summary)


def augmented_mcl_step(state, u, ranges, angles, model, *, rng):
    """One step of Augmented MCL: MCL plus new particles when the scans stop fitting (Table 8.3).

    The short- and long-term averages ``w_fast`` and ``w_slow`` follow the
    average measurement likelihood ``w_avg``; when the short-term average falls
    below the long-term one, each particle of the new set is, with probability
    ``max(0, 1 - w_fast / w_slow)``, a new pose instead of a resampled one.

    ``w_avg`` is Table 8.3's average of the weights, with the filter's own
    weights: ``sum_m w_{t-1}^[m] p(z_t | x_t^[m], m)^tau``, the tempered
    likelihood (``tau = likelihood_exponent``) averaged over the predicted
    belief (the previous weights enter because the filter does not resample at
    every step). It is computed, and ``w_slow``, ``w_fast`` are kept, in log
    space, so a scan likelihood of ``exp(-500)`` neither underflows nor
    dominates by round-off.

    New poses come from ``params.augmented.proposal``: uniform over the free
    space (Table 8.3) or, by default, from the current scan's likelihood
    (sensor resetting, :class:`AugmentedParams`). A uniform pose rarely lands
    near the true pose of a large map; a pose drawn from the scan lands where
    the scan fits the map, which includes the true pose.

    Parameters
    ----------
    state : MCLState
        Particles, log-weights and ``log_w_slow``, ``log_w_fast`` at ``t - 1``.
    u : ndarray, shape (3,)
        Odometry control since the previous step.
    ranges : ndarray, shape (K,)
        Laser scan at ``t`` [m].
    angles : ndarray, shape (K,)
        Beam angles [rad].
    model : MCLModel
        Map, likelihood field and parameters (``params.augmented``).
    rng : numpy.random.Generator
        Source of randomness, in order: the motion samples; if ``p > 0``, the
        candidate poses (:func:`~slamlib.maps.sample_free_poses`, sensor
        proposal only) and the number of new particles (``binomial``); the
        low-variance draw if the ESS calls for resampling (one uniform draw
        per kept mode with mode-preserving resampling, ``params.mode_particles``);
        if there are new
        particles, the places they take (``permutation``) and the new poses
        (``choice`` among the candidates, or ``sample_free_poses``).

    Returns
    -------
    state : MCLState
        Particles at ``t`` with updated ``log_w_slow``, ``log_w_fast`` (after
        mode-preserving resampling the particles of a mode share its mass, so
        the weights are not all equal). New
        particles take the places of randomly chosen ones and share the weight
        ``frac = p Z_U / (p Z_U + (1 - p) w_avg)`` (``p`` for the uniform
        proposal); the others keep their relative weights, scaled to
        ``1 - frac``, so a step that injects does not resample unless the ESS
        falls below ``resample_threshold * M``.
    info : MCLStepInfo
        ESS, count, whether it resampled, number of new particles, ``log_w_avg``.

    Notes
    -----
    Averaging the per-beam geometric mean ``p(z | x)^(1/K)`` instead of the
    likelihood would not be a change of scale: the ratio
    ``w_fast / w_slow`` of per-beam averages is roughly the ``K``-th root of
    Table 8.3's ratio of scan likelihoods, so a drop of the fit that Table 8.3
    would answer with ``p_inject = 0.9`` would give ``1 - 0.1^(1/18) = 0.12`` with 18
    beams. Here ``w_avg`` is the average of the tempered likelihood
    ``p(z | x)^tau`` the filter weights with, kept in log space.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.3 (Augmented MCL); Gutmann and Fox
    (2002) (the two averages); Lenser and Veloso (2000) (sensor resetting);
    Milstein, Sanchez and Williamson (2002) (resampling within clusters).
    """
    state, u, ranges, angles, model = _check_step_args(state, u, ranges, angles, model, rng)
    p = model.params
    aug = p.augmented
    poses, ll, z, a = _predict_and_weight(state, u, ranges, angles, model, rng)  # z, a: the beams kept
    log_w, log_w_avg = _update(state, poses, ll, model)
    summary = _summary(poses, log_w, state.estimate, p.estimate_hysteresis, p.estimate_radius)
    log_slow, log_fast = _averages(state, log_w_avg, aug)
    # prior probability of a new pose: max(0, 1 - w_fast / w_slow)  (Table 8.3); 1 if no particle fits at all
    p_inject = 1.0 if not np.isfinite(log_w_avg) else max(aug.p_min, _injection_probability(log_slow, log_fast))
    w, ess, do = _resample_mask(log_w, p.resample_threshold)
    m = poses.shape[0]
    n_inj, frac = 0, 0.0
    if p_inject > 0 and aug.proposal == "uniform":
        n_inj, frac = int(rng.binomial(m, p_inject)), p_inject  # each particle a random pose with probability p_inject
    elif p_inject > 0:
        cand, log_q, log_z_u = _sensor_component(model, z, a, rng)
        frac = _injected_fraction(p_inject, log_w_avg, log_z_u)
        n_inj = int(rng.binomial(m, frac))
    if do and p.mode_particles:
        idx, log_w = _mode_preserving_resample(poses, w, rng, p.mode_particles, p.mode_floor)
        poses = poses[idx]
    elif do:
        # draw i with probability proportional to w_t^[i]  (Table 8.3)
        poses = poses[particle.low_variance_resample(w, rng=rng)]
        log_w = np.full(m, -np.log(m))
    if n_inj:
        # the new poses take the places of n_inj particles chosen at random; the others keep their
        # relative weights, scaled to the belief's share 1 - frac (no resampling forced while ESS is high)
        slots = rng.permutation(m)[:n_inj]
        keep = np.ones(m, dtype=bool)
        keep[slots] = False
        poses = poses.copy()
        if aug.proposal == "uniform":  # add a random pose  (Table 8.3)
            poses[slots] = maps.sample_free_poses(model.grid, n_inj, rng=rng, threshold=p.free_threshold)
        else:  # a candidate drawn in proportion to its scan likelihood (sensor resetting)
            poses[slots] = cand[rng.choice(cand.shape[0], size=n_inj, p=np.exp(log_q))]
        log_w = log_w.copy()
        if n_inj < m and frac < 1.0:
            log_w[keep] = np.log1p(-frac) + log_w[keep] - logsumexp(log_w[keep])
            log_w[slots] = np.log(frac) - np.log(n_inj)
        else:
            log_w = np.full(m, -np.log(m))
    new = MCLState(poses=poses, log_weights=log_w, log_w_slow=log_slow, log_w_fast=log_fast, estimate=summary[3])
    return new, MCLStepInfo(ess, m, bool(do), n_inj, log_w_avg, *summary)


def kld_sample_size(k, epsilon, delta):
    """Number of particles KLD-sampling requires for ``k`` occupied bins.

    Parameters
    ----------
    k : int or ndarray of int, shape (N,)
        Number of non-empty histogram bins.
    epsilon : float
        KL-divergence bound.
    delta : float
        The bound holds with probability ``1 - delta``.

    Returns
    -------
    float or ndarray, shape (N,)
        ``(k - 1) / (2 epsilon) * (1 - 2 / (9 (k - 1)) + sqrt(2 / (9 (k - 1)))
        z_{1-delta})^3`` (the Wilson-Hilferty approximation of the chi-square
        quantile), and 0 for ``k <= 1``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.4 line 16; Fox (2001), Eq. 9.
    """
    if isinstance(k, (bool, np.bool_)) or np.asarray(k).dtype == bool:
        raise TypeError("k must be an integer number of bins (or an array of them), got a bool")
    kk = as_array(k, "k", ndim=(0, 1))
    if np.any(kk != np.floor(kk)):
        raise ValueError(f"k must hold integers (numbers of occupied bins), got {kk[kk != np.floor(kk)].ravel()[0]}")
    if np.any(kk < 0):
        raise ValueError("k must be non-negative")
    eps = as_scalar(epsilon, "epsilon", positive=True)
    dlt = as_scalar(delta, "delta", positive=True)
    if dlt >= 1.0:
        raise ValueError(f"delta must be in (0, 1), got {dlt}")
    out = _kld_bound(kk, eps, float(norm.ppf(1.0 - dlt)))
    return float(out) if out.ndim == 0 else out


def _kld_bound(k, eps, z):
    km1 = np.maximum(np.asarray(k, dtype=np.float64) - 1.0, 1.0)
    a = 2.0 / (9.0 * km1)
    # M_chi = (k-1)/(2 eps) (1 - 2/(9(k-1)) + sqrt(2/(9(k-1))) z_{1-delta})^3  (Table 8.4 line 16)
    m = km1 / (2.0 * eps) * (1.0 - a + np.sqrt(a) * z) ** 3
    return np.where(np.asarray(k) > 1, m, 0.0)


def _bin_keys(poses, size):
    ij = np.floor(poses / size).astype(np.int64) + (1 << 20)  # non-negative for |x| < 2^20 bins
    return (ij[:, 0] << 42) | (ij[:, 1] << 21) | ij[:, 2]


def kld_mcl_step(state, u, ranges, angles, model, *, rng):
    """One step of KLD-sampling MCL: the particle count adapts (Table 8.4).

    Particles are drawn from the previous set with probability proportional to
    their weights, moved, and dropped into a histogram over ``(x, y, theta)``;
    sampling stops once the count ``M`` reaches both ``n_min`` and the
    chi-square bound :func:`kld_sample_size` for the current number of
    occupied bins ``k`` (or ``n_max``). A spread-out cloud occupies many bins
    and keeps many particles; a converged one needs few.

    Draws happen ``chunk`` at a time for speed, and the count is cut exactly
    where the one-at-a-time loop of Table 8.4 would have stopped.

    Parameters
    ----------
    state : MCLState
        Particles and log-weights at ``t - 1``.
    u : ndarray, shape (3,)
        Odometry control since the previous step.
    ranges : ndarray, shape (K,)
        Laser scan at ``t`` [m].
    angles : ndarray, shape (K,)
        Beam angles [rad].
    model : MCLModel
        Map, likelihood field and parameters (``params.kld``).
    rng : numpy.random.Generator
        Source of randomness: per chunk, the indices
        (``rng.choice`` with the weights) then the motion samples.

    Returns
    -------
    state : MCLState
        ``M`` new particles weighted by the measurement (KLD-sampling always
        resamples before moving, so the new weights are the likelihoods alone).
    info : MCLStepInfo
        ESS and the new count ``M``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 8.4; Fox (2001).
    """
    state, u, ranges, angles, model = _check_step_args(state, u, ranges, angles, model, rng)
    p = model.params
    kp = p.kld
    z_quant = float(norm.ppf(1.0 - kp.delta))
    size = np.asarray(kp.bin_size, dtype=np.float64)
    w_prev = np.exp(state.log_weights)
    w_prev = w_prev / w_prev.sum()
    seen = np.empty(0, dtype=np.int64)
    k = 0
    chunks = []
    n = 0
    while True:
        c = min(kp.chunk, kp.n_max - n)
        # draw i with probability w_{t-1}^[i]; x_t ~ p(x_t | u_t, x_{t-1}^[i])  (Table 8.4 lines 8-9)
        idx = rng.choice(w_prev.size, size=c, p=w_prev)
        x = sample_motion_model_odometry(state.poses[idx], u, p.alpha, rng=rng)
        keys = _bin_keys(x, size)
        # does x fall into an empty bin? (Table 8.4 line 12)
        uniq, first = np.unique(keys, return_index=True)
        new_bin = np.zeros(c, dtype=bool)
        new_bin[first[~np.isin(uniq, seen)]] = True
        k_after = k + np.cumsum(new_bin)  # k = k + 1 for each new bin (line 13)
        count = n + np.arange(1, c + 1)  # M = M + 1 after each draw (line 18)
        # the loop runs while M < M_chi or M < M_chi_min  (line 19)
        done = (count >= _kld_bound(k_after, kp.epsilon, z_quant)) & (count >= kp.n_min)
        stop = int(np.argmax(done)) + 1 if np.any(done) else c
        chunks.append(x[:stop])
        n += stop
        k = int(k_after[stop - 1])
        seen = np.union1d(seen, keys[:stop])
        if stop < c or np.any(done) or n >= kp.n_max:
            break
    poses = np.concatenate(chunks)
    z, a = _subsample(ranges, angles, p)
    ll = _weigh(model, poses, np.zeros(poses.shape[0]), z, a)[0]  # drawn from the predicted belief: equal weights
    tll = p.likelihood_exponent * ll
    log_w = _safe_normalize(tll)  # w = p(z_t | x_t)^tau  (Table 8.4 line 10, tempered)
    finite = np.isfinite(tll)
    # the particles were drawn from the predicted belief: w_avg is their plain average
    log_w_avg = float(logsumexp(tll[finite]) - np.log(tll.size)) if np.any(finite) else -np.inf
    ess = float(particle.effective_sample_size(np.exp(log_w)))
    log_slow, log_fast = _averages(state, log_w_avg, p.augmented)  # tracked, not used
    summary = _summary(poses, log_w, state.estimate, p.estimate_hysteresis, p.estimate_radius)
    new = MCLState(poses=poses, log_weights=log_w, log_w_slow=log_slow, log_w_fast=log_fast, estimate=summary[3])
    return new, MCLStepInfo(ess, poses.shape[0], True, 0, log_w_avg, *summary)


# --------------------------------------------------------------------------- summaries
def _summary(poses, log_w, previous=None, hysteresis=1.0, radius=0.0):
    """Mean, spread, heading spread, estimate, mass of the heaviest mode, number of modes (>= 1 %), confidence."""
    w = np.exp(log_w)
    xy = w @ poses[:, :2]
    c, s = np.dot(w, np.cos(poses[:, 2])), np.dot(w, np.sin(poses[:, 2]))
    spread = float(np.sqrt(max(np.dot(w, np.sum((poses[:, :2] - xy) ** 2, axis=1)), 0.0)))
    r = min(float(np.hypot(c, s)), 1.0)
    heading_spread = float(np.sqrt(-2.0 * np.log(r))) if r > 0 else np.inf
    centres, masses = _modes(poses, w)
    estimate = centres[0]
    if previous is not None and hysteresis > 1.0:
        # keep to the previous estimate's mode while it holds at least 1/hysteresis of the heaviest mode's mass
        kept, kept_mass, _ = _mean_shift(poses, w, previous[:2])
        if kept_mass * hysteresis >= masses[0]:
            estimate = kept
    if radius > 0:  # from the mode's mean to its densest place
        estimate = _mean_shift(poses, w, estimate[:2], radius / 1.5, steps=3)[0]
    d2 = np.sum((poses[:, :2] - estimate[:2]) ** 2, axis=1)
    confidence = float(min(np.sum(w[d2 <= _CONFIDENCE_RADIUS ** 2]), 1.0))
    # circular mean heading atan2(sum w sin, sum w cos); R = |sum w e^{i theta}|
    return (np.array([xy[0], xy[1], circular_mean(poses[:, 2], w)]), spread, heading_spread, estimate,
            float(masses[0]), int(np.count_nonzero(masses >= _MODE_REPORT)), confidence)


def _modes(poses, w, max_modes=8):
    """Poses ``(K, 3)`` and masses ``(K,)`` of up to `max_modes` modes, heaviest first.

    Modes are found greedily: the heaviest mode (:func:`_cluster_mean`), then the heaviest
    among the particles not yet assigned, and so on, until less than ``_MODE_REPORT`` of the mass is left.
    """
    centre, mass, near = _cluster_mean(poses, w, with_mass=True)
    centres, masses = [centre], [mass]
    rest = w.copy()
    for _ in range(max_modes - 1):
        rest[near] = 0.0
        if rest.sum() < _MODE_REPORT:
            break
        centre, mass, near = _cluster_mean(poses, rest, with_mass=True)
        centres.append(centre)
        masses.append(mass)
    return np.array(centres), np.array(masses)


def _checked_particles(poses, log_weights):
    """``poses (M, 3)`` with ``M >= 1`` and normalised log-weights (uniform when None), checked."""
    poses = as_array(poses, "poses", (None, 3))
    if poses.shape[0] == 0:
        raise ValueError("poses must hold at least one particle")
    if log_weights is None:
        return poses, np.full(poses.shape[0], -np.log(poses.shape[0]))
    lw = as_array(log_weights, "log_weights", (poses.shape[0],), finite=False)
    if np.any(np.isnan(lw)) or np.any(lw == np.inf):
        raise ValueError("log_weights must not hold NaN or +inf")
    return poses, _safe_normalize(lw)


def particle_modes(poses, log_weights=None, *, max_modes=8):
    """The modes of a particle set: where each one is and how much of the belief it holds.

    The heaviest mode is the particles within 1.5 m of the weighted mean of
    the heaviest 3 m x 3 m block of a 1 m position histogram, after two
    mean-shift steps (the filter's estimate); the next mode is found the same
    way among the remaining particles, and so on, until less than 1 % of the
    mass is left or `max_modes` modes are found.

    Parameters
    ----------
    poses : ndarray, shape (M, 3)
        Particles.
    log_weights : ndarray, shape (M,), optional
        Log-weights (normalised or not); equal weights if omitted.
    max_modes : int, keyword-only
        Largest number of modes returned.

    Returns
    -------
    centres : ndarray, shape (K, 3)
        Weighted mean pose of every mode (circular mean heading), heaviest first.
    masses : ndarray, shape (K,)
        Posterior mass of every mode; ``masses[0]`` is the filter's confidence
        in its estimate (``MCLStepInfo.mode_mass``).

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 8.3.3 (multi-modal beliefs of global
    localization); the estimate as the heaviest cluster follows ROS ``amcl``.
    """
    poses, lw = _checked_particles(poses, log_weights)
    k = as_index(max_modes, "max_modes", lower=1)
    return _modes(poses, np.exp(lw), k)


def _cluster_mean(poses, w, cell=_CLUSTER_CELL, with_mass=False):
    """Weighted mean of the heaviest cluster: the particles near the heaviest 3 x 3 block of a position histogram."""
    ij = np.floor(poses[:, :2] / cell).astype(np.int64)
    base = ij.min(axis=0) - 1  # one empty cell of margin on every side
    ij -= base
    nx, ny = ij.max(axis=0) + 2
    hist = np.bincount(ij[:, 0] * ny + ij[:, 1], weights=w, minlength=nx * ny).reshape(nx, ny)
    block = sum(hist[1 + di:nx - 1 + di, 1 + dj:ny - 1 + dj] for di in (-1, 0, 1) for dj in (-1, 0, 1))
    bi, bj = np.unravel_index(np.argmax(block), block.shape)
    out = _mean_shift(poses, w, (base + [bi + 1, bj + 1] + 0.5) * cell, cell)
    return out if with_mass else out[0]


def _mean_shift(poses, w, centre, cell=_CLUSTER_CELL, steps=2):
    """`steps` mean-shift steps (radius 1.5 cells) from `centre`: the mode's pose, its mass and its particles."""
    near, wn = np.ones(w.size, dtype=bool), w
    for _ in range(steps):
        inside = np.sum((poses[:, :2] - centre) ** 2, axis=1) <= (1.5 * cell) ** 2
        if not np.any(w[inside] > 0):
            break
        near, wn = inside, w[inside]
        centre = (wn / wn.sum()) @ poses[near, :2]
    return np.array([centre[0], centre[1], circular_mean(poses[near, 2], wn)]), float(wn.sum()), near


def particle_summary(poses, log_weights=None):
    """Weighted mean pose and spread of a particle set.

    Parameters
    ----------
    poses : ndarray, shape (M, 3)
        Particles.
    log_weights : ndarray, shape (M,), optional
        Log-weights (normalised or not); equal weights if omitted.

    Returns
    -------
    mean : ndarray, shape (3,)
        Weighted mean position and circular mean heading.
    spread : float
        Weighted RMS distance of the positions from the mean [m].
    heading_spread : float
        Circular standard deviation ``sqrt(-2 log R)`` of the headings [rad].

    References
    ----------
    Thrun, Burgard & Fox (2005), Sec. 4.3 (particle representation of the
    belief).
    """
    poses, lw = _checked_particles(poses, log_weights)
    return _summary(poses, lw)[:3]


def scan_endpoints(pose, ranges, angles, *, z_max=np.inf, sensor_offset=0.25):
    """World coordinates of the end points of a scan taken from one pose.

    Parameters
    ----------
    pose : ndarray, shape (3,)
        Robot pose ``[x, y, theta]``.
    ranges : ndarray, shape (K,)
        Ranges [m].
    angles : ndarray, shape (K,)
        Beam angles in the laser frame [rad].
    z_max : float
        Readings at or beyond `z_max` are dropped (they hit nothing).
    sensor_offset : float
        Forward offset of the laser from the robot's centre [m].

    Returns
    -------
    ndarray, shape (K', 2)
        End points of the readings shorter than `z_max`.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3 lines 4-5.
    """
    pose = as_array(pose, "pose", (3,))
    ranges, angles = as_scan(ranges, angles)
    z_max = as_scalar(z_max, "z_max", positive=True, finite=False)
    off = as_scalar(sensor_offset, "sensor_offset")
    keep = ranges < z_max
    c, s = np.cos(pose[2]), np.sin(pose[2])
    sx, sy = pose[0] + off * c, pose[1] + off * s
    # x_z = x + x_sens cos(theta) + z cos(theta + theta_sens)  (Table 6.3 lines 4-5)
    ang = pose[2] + angles[keep]
    return np.column_stack([sx + ranges[keep] * np.cos(ang), sy + ranges[keep] * np.sin(ang)])


def endpoint_distances(model, pose, ranges, angles):
    """Distance from each scan end point to the nearest obstacle of the map.

    A consistency check when there is no ground truth: if the pose is right,
    the end points lie on walls and these distances are a few centimetres.

    Parameters
    ----------
    model : MCLModel
        Map and its likelihood field (``params.z_max`` and
        ``params.sensor_offset`` are used).
    pose : ndarray, shape (3,)
        Robot pose.
    ranges : ndarray, shape (K,)
        A scan [m]; every beam is used (no subsampling).
    angles : ndarray, shape (K,)
        Beam angles [rad].

    Returns
    -------
    ndarray, shape (K',)
        Distances [m] (clipped at ``params.max_dist``; ``inf`` in unknown
        cells or outside the map) of the beams shorter than ``z_max``.

    References
    ----------
    Thrun, Burgard & Fox (2005), Table 6.3 line 6 (``dist``).
    """
    model = _check_model(model)
    p = model.params
    ranges, angles = as_scan(ranges, angles)
    pts = scan_endpoints(pose, ranges, angles, z_max=p.z_max, sensor_offset=p.sensor_offset)
    return model.field.distance_at(pts)


# --------------------------------------------------------------------------- runs
_STEP = {"mcl": mcl_step, "augmented": augmented_mcl_step, "kld": kld_mcl_step}


def run_mcl(model, odom_poses, ranges, angles, *, rng, variant="augmented", init=None, times=None, snapshots=0,
            max_steps=None):
    """Run a Monte Carlo localization filter over a log.

    Parameters
    ----------
    model : MCLModel
        Map, likelihood field and parameters (from :func:`prepare_mcl`).
    odom_poses : ndarray, shape (L, 3)
        Odometry pose at every scan.
    ranges : ndarray, shape (L, K)
        Laser scans [m].
    angles : ndarray, shape (K,)
        Beam angles in the laser frame [rad].
    rng : numpy.random.Generator
        Source of randomness.
    variant : {"augmented", "mcl", "kld"}
        :func:`augmented_mcl_step` (Table 8.3 with sensor resetting, the
        default), :func:`mcl_step` (Table 8.2) or :func:`kld_mcl_step`
        (Table 8.4).
    init : MCLState or ndarray, shape (M, 3), optional
        Initial particles; uniform over free space (global localization) if
        omitted.
    times : ndarray, shape (L,), optional
        Time stamps of the scans [s].
    snapshots : int or sequence of int
        Store the particles after this many evenly spaced steps (an int,
        including the first and last), or after the listed steps.
    max_steps : int, optional
        Stop after this many filter steps.

    Returns
    -------
    MCLResult
        Per-step mean, spread, ESS, particle count, injected particles,
        ``w_slow`` / ``w_fast``, the stored snapshots and the final state.

    References
    ----------
    Thrun, Burgard & Fox (2005), Tables 8.2, 8.3 and 8.4.
    """
    model = _check_model(model)
    check_rng(rng)
    p = model.params
    odom = as_array(odom_poses, "odom_poses", (None, 3))
    L = odom.shape[0]
    z_all = as_array(ranges, "ranges", (L, None))
    ang = as_array(angles, "angles", (z_all.shape[1],))
    t_all = np.arange(L, dtype=np.float64) if times is None else as_array(times, "times", (L,))
    if variant not in _STEP:
        raise ValueError(f"variant must be one of {_VARIANTS}, got {variant!r}")
    step = _STEP[variant]
    index, u = odometry_steps(odom, min_translation=p.min_translation, min_rotation=p.min_rotation)
    if max_steps is not None:
        n_max = as_index(max_steps, "max_steps", lower=1)
        index, u = index[:n_max], u[:n_max]
    S = index.size
    if isinstance(snapshots, (int, np.integer)) and not isinstance(snapshots, bool):
        n_snap = as_index(snapshots, "snapshots")
        snap = np.unique(np.round(np.linspace(0, S - 1, n_snap)).astype(np.intp)) if n_snap else np.empty(0, np.intp)
    else:
        snap = np.unique(np.asarray([as_index(s, "snapshots", S) for s in snapshots], dtype=np.intp))
    t0 = time.perf_counter()  # the run's time includes the start from the first scan
    if init is None:  # global localization: uniform, or drawn by the first scan (params.init_candidates)
        state = mcl_initialize(model, rng=rng, scan=(z_all[index[0]], ang) if S else None)
    elif isinstance(init, MCLState):
        state = init
    else:
        state = mcl_initialize(model, rng=rng, poses=init)

    mean = np.empty((S, 3))
    estimate = np.empty((S, 3))
    spread = np.empty(S)
    hspread = np.empty(S)
    ess = np.empty(S)
    count = np.empty(S, dtype=np.intp)
    injected = np.zeros(S, dtype=np.intp)
    log_w_avg = np.empty(S)
    log_w_slow = np.empty(S)
    log_w_fast = np.empty(S)
    mode_mass = np.empty(S)
    n_modes = np.empty(S, dtype=np.intp)
    confidence = np.empty(S)
    shots = []
    snap_set = set(snap.tolist())
    for s in range(S):  # a loop over time steps; every step is vectorised over particles
        state, info = step(state, u[s], z_all[index[s]], ang, model, rng=rng)
        mean[s], estimate[s], spread[s], hspread[s] = info.mean, info.estimate, info.spread, info.heading_spread
        ess[s], count[s], injected[s] = info.ess, info.n_particles, info.n_injected
        log_w_avg[s], log_w_slow[s], log_w_fast[s] = info.log_w_avg, state.log_w_slow, state.log_w_fast
        mode_mass[s], n_modes[s], confidence[s] = info.mode_mass, info.n_modes, info.confidence
        if s in snap_set:
            shots.append(state)
    runtime = time.perf_counter() - t0
    return MCLResult(scan_index=index, t=t_all[index], mean=mean, estimate=estimate, spread=spread, heading_spread=hspread, ess=ess,
                     n_particles=count, n_injected=injected, log_w_avg=log_w_avg, log_w_slow=log_w_slow,
                     log_w_fast=log_w_fast, snapshot_steps=snap,
                     snapshots=shots, final=state, runtime=runtime, mode_mass=mode_mass, n_modes=n_modes,
                     confidence=confidence)

"""What the estimator knows of the bench before the sweep, and which corrections it applies.

The estimator never sees the truth: it gets the nominal sensor geometry, the
engine (for the known excitation), the mounts (for the suspension
correction), the crank-train spin inertia (gyroscopic correction) and the
nominal or weighed mass, cog and inertia (starting point for the few
linearised terms and for row weighting).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from estimator.vec import cross, skew

# (rpm, orders) -> (force (n_o, 3) complex N, moment about reference_point (n_o, 3) complex N m)
ExcitationFn = Callable[[float, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: (rpm (P,), orders (P,)) of P (frame, order) pairs -> (force (P, 3) complex N, moment
#: about reference_point (P, 3) complex N m): the pairs of a batch in one call
PairExcitationFn = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
#: (orders, pressure spectrum of a frame) -> (n_orders, 3) complex N m gas moment
GasMomentFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: What an ``excitation`` (or ``gas_moment``) may also offer, as its attribute ``many``:
#: the frames of a run in one call, each frame's (n_orders, 3) the same bits as its own
#: call. ``excitation.many(rpm list (n,), orders)`` -> force and moment (n, n_orders, 3);
#: ``gas_moment.many(orders, spectra (n, n_half))`` -> (n, n_orders, 3). The scalar
#: call stays the contract (test helpers implement only that); ``many`` is looked up on
#: the callable itself, so replacing the callable in a setup replaces both.
ExcitationManyFn = Callable[[list[float], np.ndarray], tuple[np.ndarray, np.ndarray]]
GasMomentManyFn = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: What a ``d_excitation`` (:data:`PairExcitationFn`) may also offer, as its attribute
#: ``split``: ``split(key)`` of the sorted distinct orders ``key`` (K,) -> the gas and
#: the unit-speed parts (K, 2, 3) complex ([force, moment]), the pairs' derivative being
#: ``gas[i] + omega^2 unit[i]`` (omega rad/s, i the pair's order in ``key``): the
#: compiled model-input rows (estimator.compiled_model_rows) gather them in their loop.
PairExcitationSplitFn = Callable[[tuple[float, ...]], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class MountStiffness:
    """One mount: position (3,) m and complex stiffness (3, 3) N/m in the bench frame."""

    name: str
    position: np.ndarray
    stiffness: np.ndarray


@dataclass(frozen=True)
class Corrections:
    """Model terms beyond the paper; each on by default when its data exist."""

    suspension: bool = True  # mount reactions -K u from known mount stiffness
    gyroscopic: bool = True  # Omega x H of the spinning crank train
    unbalance: bool = True  # residual static unbalance at H1, estimated
    # and its couple (its location along the crank, or a two-plane unbalance); off by
    # default: it takes one complex moment direction of order 1 from the inertia (noise-
    # free 8 s i3 sweep: Ixz 0.13 % off instead of within 0.1 %)
    unbalance_location: bool = False
    crank_offset: bool = True  # crank-angle reference offset, estimated
    # one stiffness scale per mount estimated with the rest (the reactions scale like
    # 1 / (h omega)^2, the inertia terms do not: a sweep separates them); for benches
    # whose mount data are uncertain. Needs a known mass (the scales and 1/m multiply).
    mount_scale: bool = False
    # each channel's gain and each sensor's alignment estimated with the rest, the
    # declared tolerances as their priors (the sweep's varied motion separates them)
    self_calibration: bool = False
    # each channel weighed in the rigid fit by its noise, measured along the sweep
    # (estimator/channel_noise.py); off: equal weights
    channel_weights: bool = False


@dataclass(frozen=True)
class Tolerances:
    """Declared sensor uncertainties (1 sigma) propagated into the intervals (type B)."""

    gain_rel: float = 0.01  # channel sensitivity, relative
    alignment_rad: float = float(np.radians(1.0))  # each sensor's orientation
    position_m: float = 0.002  # each sensor's position


@dataclass(frozen=True)
class ModelInput:
    """A model input the estimator takes as known, with its declared 1-sigma uncertainty
    (propagated into the intervals as type B, :mod:`estimator.model_inputs`).

    ``kind``: ``excitation``: ``d_excitation`` gives d(force N, moment N m about
    ``reference_point``)/d(input) of (frame, order) pairs (the gas model, the moving
    masses, the crankcase pressure); ``spin_inertia``: the crank train's spin inertia, ``std``
    in kg m^2 (the gyroscopic term); ``mount``: the stiffness of mount ``mount`` (its
    index in ``mounts``), ``std`` relative.
    """

    name: str
    kind: Literal["excitation", "spin_inertia", "mount"]
    std: float
    d_excitation: PairExcitationFn | None = None
    mount: int = -1


@dataclass(frozen=True)
class Gates:
    """Frame gating thresholds."""

    max_relative_residual: float = 0.05  # rigid fit residual / signal, per order
    baseline_frames: int = 15  # first frames of each order that set its residual baseline
    residual_growth: float = 2.0  # reject when the residual exceeds growth * baseline + margin
    residual_margin: float = 0.002
    # reject an order whose rigid motion bends by more than this over three frames
    # 720 deg apart (relative second difference): off the mass line, near a mode
    max_curvature: float = 0.005
    max_rpm_change: float = 0.03  # relative rpm change across the frame window
    min_mode_ratio: float = 1.25  # order frequency / highest rigid-body mode
    rpm_range: tuple[float, float] = (0.0, float("inf"))
    # Use only frames 720 deg apart: the dsp's 720 deg windows overlap by one
    # revolution at one frame per revolution, so neighbouring frames share half
    # their samples and their errors; counting both would overstate the information.
    independent_frames: bool = True


@dataclass(frozen=True)
class FrameConstants:
    """What the rows of every frame take from the setup (:func:`estimator.equations.frame_rows`):
    built once per setup, as building them per call was a tenth of the call at a dozen
    (frame, order) pairs."""

    mount_positions: np.ndarray  # (M, 3) m
    mount_stiffness: np.ndarray  # (M, 3, 3) complex N/m
    skew_p: np.ndarray  # (M, 1, 3, 3) skew(p_i)
    skew_p_t: np.ndarray  # (M, 3, 3) skew(p_i).T
    skew_s: np.ndarray  # (3, 3) skew(crank axis)
    c_it: np.ndarray  # (3,) c - i t, t = s x c
    skew_ref_t: np.ndarray  # (3, 3) skew(reference point).T


@dataclass(frozen=True)
class EstimatorSetup:
    """The bench as the estimator sees it (nominal values; SI, bench frame).

    Attributes
    ----------
    channels : channel names in the order of ``positions``/``directions``.
    sensor_of_channel : (n_ch,) int, index of the sensor carrying each channel.
    positions, directions : (n_ch, 3) channel points (m) and unit axes.
    reference_point : (3,) m, point the excitation moment is given about.
    unbalance_point : (3,) m, where a residual static unbalance acts (on the crank axis).
    crank_axis, cylinder_axis : (3,) unit vectors; ``t = s x c`` completes the rotating frame.
    spin_inertia : kg m^2 of the crank train about ``crank_axis``.
    excitation : the known engine excitation.
    mounts : mount stiffnesses (empty: free body).
    mass_nominal, mass_known : kg, and whether it is an input (weighed) or estimated.
    cog_nominal : (3,) m; inertia_nominal : (3, 3) kg m^2.
    mode_max_hz : highest rigid-body mode of the nominal model (None: unknown).
    gas_moment : the gas moment from a frame's measured cylinder-pressure spectrum
        (``frame.spectrum``); None when ``excitation`` includes a modelled gas torque.
        Measured in the frame's own crank angle, it turns with the motion under a
        reference offset or a 360 deg slip, so half orders need no sign hypothesis.
    model_inputs : the model inputs taken as known, with their declared tolerances.
    """

    channels: tuple[str, ...]
    sensor_of_channel: np.ndarray
    positions: np.ndarray
    directions: np.ndarray
    reference_point: np.ndarray
    unbalance_point: np.ndarray
    crank_axis: np.ndarray
    cylinder_axis: np.ndarray
    spin_inertia: float
    excitation: ExcitationFn
    mounts: tuple[MountStiffness, ...]
    mass_nominal: float
    mass_known: bool
    cog_nominal: np.ndarray
    inertia_nominal: np.ndarray
    mode_max_hz: float | None = None
    channel_weights: np.ndarray | None = None
    corrections: Corrections = field(default_factory=Corrections)
    tolerances: Tolerances = field(default_factory=Tolerances)
    gates: Gates = field(default_factory=Gates)
    gas_moment: GasMomentFn | None = None
    # the model inputs whose declared tolerances join the type-B covariance
    model_inputs: tuple[ModelInput, ...] = ()

    @property
    def n_sensors(self) -> int:
        return int(np.max(self.sensor_of_channel)) + 1

    @functools.cached_property  # (frozen: nothing it is built from changes)
    def frame_constants(self) -> FrameConstants:
        p = np.array([mount.position for mount in self.mounts], dtype=float).reshape(-1, 3)
        skew_p = np.array([skew(pi) for pi in p]).reshape(-1, 1, 3, 3)
        return FrameConstants(
            mount_positions=p,
            mount_stiffness=np.array([mount.stiffness for mount in self.mounts]),
            skew_p=skew_p,
            skew_p_t=skew_p[:, 0].transpose(0, 2, 1),
            skew_s=skew(self.crank_axis),
            c_it=self.cylinder_axis - 1j * cross(self.crank_axis, self.cylinder_axis),
            skew_ref_t=skew(self.reference_point).T,
        )

"""Foot locking (``mdvae denoise --feet lock``): feet that stand on the ground stay on it.

A post-process on a motion (in ``mdvae denoise``, the denoised one), optionally given the input
it was made from (same frames):

1. **Contacts.** The motion's foot joints, smoothed in time (Gaussian, ``smooth_s``), go
   through the shared definition (:func:`mdvae_cli.motion.contacts.contacts_of_feet`: a foot
   joint low and slow), with a height band (``height_tol``, 7 cm) and a speed threshold
   (``speed_tol``, 0.8 m/s) above the ones for clean motion (5 cm, 0.2 m/s), because a
   denoised foot that should stand still slides (by 19 to 48 cm/s on average on clean to very
   noisy clips) and wavers in height; both were set on held-out dance, kicks and acrobatics as
   well as walks, erring toward a missed contact (a little skate) rather than a wrong one (a
   foot held where the truth moves it). With the input given, the noisier its feet
   (:func:`input_jitter` from ``noisy_from`` to ``noisy_to``), the wider both thresholds and
   the smaller ``keep`` (to their ``noisy_`` values, :func:`for_noise`): a noisier input's
   denoised feet slide and waver more where the truth stands, and the vertex error the
   denoising leaves is larger than a wrong contact's. Gaps up to ``max_gap_s`` are filled,
   contacts shorter than ``min_contact_s`` dropped, and each contact is extended by
   ``extend_s`` at both ends (a foot that slides as it lands or lifts is caught there too).
   Contacts are found on the denoised motion, not on a noisy input, whose feet shake too much
   (docs/model.md, "Feet and floor").
2. **Floor**: :func:`mdvae_cli.motion.contacts.estimate_floor`, from the motion's lowest sole
   points where the feet are down.
3. **Goals in contact.** A foot joint (ankle or ball) is held at one anchor per contact run,
   its mean horizontal position over the run, keeping ``keep`` of its own horizontal movement
   about it (smoothed over ``keep_smooth_s``: its drift, not its jitter); its height puts the
   foot's lowest sole point on the floor. When the input is
   given and clean (its foot joints' jitter, :func:`input_jitter`, under ``trust_below``), the
   goal is instead the input's own foot joints (lightly smoothed): a clean take keeps the feet
   it came with, rolling from heel to toe; between ``trust_below`` and ``distrust_above`` the
   two goals are blended.
4. **Fades.** A run's correction fades out over ``blend_s`` before and after it (smoothstep),
   in the swing: a fade inside the contact would be sliding itself; ``pin`` times the fade's
   weight (times 1 - the input's trust) of its horizontal part takes the joint toward its goal
   rather than moving it with the motion, so a foot the motion lifts early or puts down late
   slides less next to the run. Anywhere else, a foot whose sole is under the floor gets a
   goal on it.
5. **Leg IK that keeps the knee's bend** (:func:`mdvae_cli.infer.leg_ik.swing_ik`): each held
   leg swings about its hip to put the ankle over its goal, the knee bent as the motion has it;
   the knee turns only by a damped least-squares step (``knee_stiffness``, ``bend_stiffness``:
   metres of miss worth a radian of knee), so a nearly straight knee is never pulled straight
   and the part of a goal the bend cannot reach is left as a small height miss. A foot more
   than ``sunk_tol`` under the floor may bend its knee as far as lifting it needs (off by
   default). The foot turns with the hip's swing only (both joints held: the ankle goes
   halfway to where the ball's goal puts it). ``passes`` times, each with the soles as the last
   left them. Frames more than ``blend_s`` from a contact (no foot under the floor), legs
   without a target, and every joint but hips, knees and ankles keep their exact values.

Every step is vectorised over frames (no Python loop over frames or contact runs); the legs
are posed and solved ``CHUNK_FRAMES`` at a time, so memory stays flat on long takes.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

from mdvae_cli.body.data import SMPL_PARENTS
from mdvae_cli.body.skinning import BodyModel
from mdvae_cli.filters import gaussian_smooth
from mdvae_cli.geometry.rotations_np import rotvec_to_rotmat
from mdvae_cli.infer.contact_runs import clean_contacts, fade_weights, hold_targets, travel_anchors
from mdvae_cli.infer.fill import holes_from
from mdvae_cli.infer.foot_jitter import JITTER_FPS, at_jitter_rate, input_jitter, jitter_of  # noqa: F401
from mdvae_cli.infer.leg_ik import (
    LEGS,
    LegModel,
    feet_of,
    leg_chain,
    leg_rotations,
    pose_legs,
    solve_legs,
)
from mdvae_cli.infer.noise_blend import source_spikes
from mdvae_cli.motion.contacts import (
    FOOT_SIDE,
    contacts_of_feet,
    estimate_floor,
    foot_of_joints,
)
from mdvae_cli.motion.holes import observed
from mdvae_cli.motion.motion import Motion

#: per leg (left, right): its (ankle, ball) columns of FOOT_JOINTS
LEG_COLUMNS = ((0, 2), (1, 3))


@dataclass(frozen=True)
class FootLockConfig:
    """Settings of :func:`lock_feet` (times in seconds, whatever the frame rate).

    smooth_s: std of the Gaussian on the foot joints before contacts are found; height_tol (m),
    speed_tol (m/s): the contact thresholds (:func:`contacts_of_feet`); min_contact_s: shorter
    contacts are dropped; max_gap_s: shorter gaps inside a contact are filled; extend_s:
    contacts are extended by this at both ends; blend_s: the fade of a contact's correction
    before and after it; keep: the share of its own horizontal movement a held joint keeps
    (0 = nailed to its anchor); trust_below, distrust_above (m): the input's foot jitter under
    which its own feet are the goal, and over which they are ignored; reference_smooth_s: std
    of the Gaussian on the input's feet used as goal; clean_jitter (m): under this foot
    jitter the input's feet are goals nearer as they came, that smoothing and the lift of a
    foot joint under its height over the floor scaled by jitter / clean_jitter (0: always in
    full; the jitter read as at 30 Hz, :func:`input_trust`); passes: IK passes (a second
    puts the soles on the floor as posed by the first);
    knee_stiffness, bend_stiffness (m/rad): how far an ankle may miss a goal further from
    (nearer to) the hip than the knee's bend gives, rather than straighten (bend) the knee by
    a radian; sunk_tol (m): a foot deeper than this under the floor bends its knee as far as
    needed to be lifted (None, the default: never);
    keep_smooth_s: std of the Gaussian on the movement a held joint keeps (``keep``);
    noisy_from, noisy_to (m): the input's foot jitter over which height_tol, speed_tol and keep
    go linearly to noisy_height_tol, noisy_speed_tol and noisy_keep (:func:`for_noise`);
    travel_tol (m), travel_jitter: a held joint straying over a run further than travel_tol
    (plus, over 30 Hz, travel_jitter times the input's foot jitter; none over noisy_from)
    from its mean travels (``contact_runs.travel_anchors``): held to its mean within travel_s
    either side; over 30 Hz the tolerance is scaled by 30 / fps (the denoised feet err less
    there: a 120 Hz squat's travel is the take's own) and that mean, tapered, moves only by its
    speed over travel_stick (m/s; ``contact_runs.stuck_path``: a denoised standing foot's
    wander is slow; 0: the plain mean); pin: times the fade's weight, the share of a
    fade's horizontal correction that takes the joint toward its goal
    (``contact_runs.hold_targets``).
    """

    smooth_s: float = 0.05
    height_tol: float = 0.07
    speed_tol: float = 0.8
    min_contact_s: float = 0.1
    max_gap_s: float = 0.07
    extend_s: float = 0.034
    blend_s: float = 0.2
    keep: float = 0.1
    trust_below: float = 0.02
    distrust_above: float = 0.08
    reference_smooth_s: float = 0.05
    clean_jitter: float = 0.015
    passes: int = 1
    knee_stiffness: float = 0.5
    bend_stiffness: float = 0.5
    sunk_tol: float | None = None
    keep_smooth_s: float = 0.1
    noisy_from: float = 0.12
    noisy_to: float = 0.22
    noisy_height_tol: float = 0.1
    noisy_speed_tol: float = 1.2
    noisy_keep: float = 0.0
    travel_tol: float = 0.15
    travel_jitter: float = 1.0
    travel_s: float = 0.25
    travel_stick: float = 0.05
    pin: float = 0.5

    def __post_init__(self):
        for name in ("smooth_s", "min_contact_s", "max_gap_s", "extend_s", "blend_s",
                     "trust_below", "reference_smooth_s", "clean_jitter", "keep_smooth_s",
                     "travel_tol", "travel_jitter", "travel_s", "travel_stick"):  # fmt: skip
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if not (self.height_tol > 0 and self.speed_tol > 0):
            raise ValueError("height_tol and speed_tol must be > 0")
        if not (0 <= self.keep <= 1 and 0 <= self.pin <= 1):
            raise ValueError(f"keep and pin must be in [0, 1], got {self.keep}, {self.pin}")
        if not (self.noisy_to > self.noisy_from and 0 <= self.noisy_keep <= 1):
            raise ValueError("noisy_to must be larger than noisy_from, noisy_keep in [0, 1]")
        if not (self.noisy_height_tol > 0 and self.noisy_speed_tol > 0):
            raise ValueError("noisy_height_tol and noisy_speed_tol must be > 0")
        if not self.distrust_above > self.trust_below:
            raise ValueError("distrust_above must be larger than trust_below")
        if not (self.knee_stiffness > 0 and self.bend_stiffness >= 0):
            raise ValueError("knee_stiffness must be > 0 and bend_stiffness >= 0")
        if self.sunk_tol is not None and not self.sunk_tol >= 0:
            raise ValueError(f"sunk_tol must be >= 0 or None, got {self.sunk_tol}")
        if self.passes < 1:
            raise ValueError(f"passes must be >= 1, got {self.passes}")

    def to_dict(self) -> dict:
        return asdict(self)


# --------------------------------------------------------------------------------------------
# contacts over time


def detect_contacts(feet: np.ndarray, fps: float, cfg: FootLockConfig) -> np.ndarray:
    """Where the feet are down, robust to sliding and to noise.  feet: (T, 4, 3) the foot
    joints (``FOOT_JOINTS`` order) -> (T, 4) bool"""
    smooth = gaussian_smooth(feet, cfg.smooth_s * fps) if len(feet) > 1 else feet
    contacts = contacts_of_feet(smooth, fps, height_tol=cfg.height_tol, speed_max=cfg.speed_tol)
    return clean_contacts(
        contacts,
        math.ceil(cfg.min_contact_s * fps - 1e-9),
        round(cfg.max_gap_s * fps),
        round(cfg.extend_s * fps),
    )


#: a long take's jitter is read on this many triples of consecutive frames, spread evenly
JITTER_TRIPLES = 4096


# --------------------------------------------------------------------------------------------
# the whole step


def input_trust(
    source: Motion, model: LegModel, cfg: FootLockConfig, cleaned: np.ndarray | None = None
) -> tuple[float, np.ndarray | None, float, float]:
    """How far the input's own feet are a goal (1 clean, 0 noisy), and those feet smoothed
    (None when the trust is 0: a noisy take's legs are posed only on ``JITTER_TRIPLES``
    triples of frames, enough for the median), their jitter (:func:`input_jitter`, m) and
    the jitter as at 30 Hz that :func:`clean_scale` reads (``at_jitter_rate`` with
    ``cleaned``, the cleaned motion's feet (T, 4, 3)). model: the legs of the input's shape.
    -> (trust, (T, 4, 3) or None, jitter, jitter as at 30 Hz)"""
    T = source.num_frames
    rated = cleaned is not None and source.fps < JITTER_FPS and T >= 3
    if T > 3 * JITTER_TRIPLES:
        starts = np.linspace(0, T - 3, JITTER_TRIPLES).astype(int)
        frames = (starts[:, None] + np.arange(3)).reshape(-1)
        root = rotvec_to_rotmat(np.asarray(source.root_orient[frames], dtype=np.float64))
        pos, _ = leg_chain(
            root, leg_rotations(source, frames), source.trans[frames] + model.pelvis, model.bones
        )
        f = feet_of(pos).reshape(JITTER_TRIPLES, 3, 4, 3)
        d2 = f[:, 0] - 2 * f[:, 1] + f[:, 2]
        c = cleaned[frames].reshape(JITTER_TRIPLES, 3, 4, 3) if rated else None
        d2_cleaned = None if c is None else c[:, 0] - 2 * c[:, 1] + c[:, 2]
        src = None
    else:
        src = feet_of(pose_legs(source, model, soles=False)[0])
        d2 = src[:-2] - 2 * src[1:-1] + src[2:]
        d2_cleaned = cleaned[:-2] - 2 * cleaned[1:-1] + cleaned[2:] if rated else None
    jitter = jitter_of(d2) if len(d2) else 0.0
    at_30 = jitter_of(at_jitter_rate(d2, d2_cleaned, source.fps)) if rated else jitter
    span = cfg.distrust_above - cfg.trust_below
    trust = float(np.clip((cfg.distrust_above - jitter) / span, 0.0, 1.0))
    if trust == 0:
        return 0.0, None, jitter, at_30
    if src is None:
        src = feet_of(pose_legs(source, model, soles=False)[0])
    if len(src) > 1:
        src = gaussian_smooth(src, clean_scale(cfg, at_30) * cfg.reference_smooth_s * source.fps)
    return trust, src, jitter, at_30


def clean_scale(cfg: FootLockConfig, jitter: float) -> float:
    """How far the lock may move an input's own feet, by their jitter (m): 1 at
    ``clean_jitter`` and over, down to 0 for a take whose feet do not shake at all (its feet
    are the goal as they came: a clean take's roll and toe-off are its own)."""
    return 1.0 if cfg.clean_jitter == 0 else min(1.0, jitter / cfg.clean_jitter)


def for_noise(cfg: FootLockConfig, jitter: float) -> FootLockConfig:
    """The settings for an input whose feet shake by ``jitter`` (m): from ``noisy_from`` to
    ``noisy_to`` the contact thresholds and ``keep`` go linearly to their ``noisy_`` values
    (the noisier the input, the more the denoised feet slide and waver where the truth stands,
    and the more vertex error the denoising leaves for a wrong contact to hide in)."""
    a = float(np.clip((jitter - cfg.noisy_from) / (cfg.noisy_to - cfg.noisy_from), 0.0, 1.0))
    if a == 0:
        return cfg
    mix = lambda low, high: (1 - a) * low + a * high  # noqa: E731
    return replace(
        cfg,
        height_tol=mix(cfg.height_tol, cfg.noisy_height_tol),
        speed_tol=mix(cfg.speed_tol, cfg.noisy_speed_tol),
        keep=mix(cfg.keep, cfg.noisy_keep),
    )


def lock_feet(
    motion: Motion,
    body: BodyModel,
    cfg: FootLockConfig | None = None,
    source: Motion | None = None,
) -> Motion:
    """``motion`` with its feet held still on the floor where they are down (module doc).

    source: the input ``motion`` was made from (same frames), or None; where its feet are a
    goal (a clean take), its spikes in the legs (``noise_blend.source_spikes``: a knee flicked
    for one frame would put the foot somewhere the leg never went) read as ``motion``'s frames
    (:func:`without_spikes`). Returns a copy; hips,
    knees and ankles change only near contacts and where a foot is under the floor, and only on
    legs that have a target there. Vectorised over frames, the legs solved ``CHUNK_FRAMES`` at a
    time (memory flat on long takes).
    """
    cfg = cfg or FootLockConfig()
    if source is not None and source.num_frames != motion.num_frames:
        raise ValueError(f"{motion.num_frames} frames to lock, {source.num_frames} in the input")
    model = LegModel.build(body, motion.betas)
    trust, reference, lift_share, travel_tol = 0.0, None, 1.0, cfg.travel_tol
    pos, soles = pose_legs(motion, model)
    feet = feet_of(pos)
    if source is not None:
        same = np.array_equal(source.betas, motion.betas)
        legs = model if same else LegModel.build(body, source.betas)
        trust, reference, jitter, at_30 = input_trust(source, legs, cfg, feet)
        unspiked = without_spikes(source) if trust > 0 else source
        if unspiked is not source:  # its feet are a goal: not where its spikes put them
            unspiked = holes_from(unspiked, motion)
            trust, reference, jitter, at_30 = input_trust(unspiked, legs, cfg, feet)
        cfg = for_noise(cfg, jitter)
        # a very noisy input's feet wander as far as a shuffle goes once denoised; over 30 Hz,
        # where the tolerance is scaled down to the rate, a noisier one's wander further
        # (at 30 Hz and under a shuffle's steps are the take's: the tolerance alone)
        if jitter > cfg.noisy_from:
            travel_tol = math.inf
        elif motion.fps > JITTER_FPS:
            travel_tol += cfg.travel_jitter * jitter
        # a clean take's feet are lifted only by the share of the goal that is not its own
        lift_share = 1.0 - trust * (1.0 - clean_scale(cfg, at_30))
    travel_tol *= min(1.0, JITTER_FPS / motion.fps)  # over 30 Hz the denoised feet err less
    contacts = detect_contacts(feet, motion.fps, cfg)
    if not contacts.any():
        return motion.with_body()
    floor = estimate_floor(soles, foot_of_joints(contacts))
    kept = feet[..., :2]
    if len(feet) > 1 and cfg.keep_smooth_s > 0:
        kept = gaussian_smooth(kept, cfg.keep_smooth_s * motion.fps)
    stick = cfg.travel_stick / motion.fps if motion.fps > JITTER_FPS else 0.0
    anchors = travel_anchors(feet[..., :2], kept, contacts, travel_tol,
                             round(cfg.travel_s * motion.fps), stick)  # fmt: skip
    goals = feet.copy()
    goals[..., :2] = anchors + cfg.keep * (kept - anchors)
    weights = fade_weights(contacts, round(cfg.blend_s * motion.fps))
    # (T, 2) a foot deep under the floor: its knee bends as far as lifting it needs
    sunk = soles < floor - (math.inf if cfg.sunk_tol is None else cfg.sunk_tol)
    under = (soles < floor)[:, list(FOOT_SIDE)]  # a foot under the floor: both its joints
    held = contacts | (weights.sum(-1) > 0) | under
    f = np.flatnonzero(held.any(1))
    columns = np.asarray(LEG_COLUMNS)
    free = ~contacts[f]
    # each joint's height above its foot's lowest sole point, as posed (then as the last pass
    # left it)
    clearance = feet[f, :, 2] - soles[f][:, list(FOOT_SIDE)]
    new_rotvecs = None
    for i in range(cfg.passes):
        heights = feet[..., 2].copy()
        heights[f] = floor + clearance
        goals[..., 2] = heights
        goal = goals if reference is None else trust * reference + (1 - trust) * goals
        targets = hold_targets(feet, contacts, goal, weights, cfg.pin * (1 - trust))[f]
        lift = lift_share * np.maximum(heights[f] - targets[..., 2], 0.0)
        targets[..., 2] = np.where(free, targets[..., 2] + lift, targets[..., 2])
        last = i == cfg.passes - 1
        stiff = (cfg.knee_stiffness, cfg.bend_stiffness)
        clearance, new_rotvecs = solve_legs(
            motion, model, f, targets[:, columns], held[f][:, columns], sunk[f], stiff, last
        )
    out = motion.pose_body.copy()
    b, leg = np.nonzero(held[f][:, columns].any(-1))  # frames where each leg has a target
    joints = np.asarray(LEGS)[leg, :3] - 1  # pose_body rows of hip, knee, ankle
    out[f[b, None], joints] = new_rotvecs[b, leg]
    return motion.with_body(pose_body=out)


def lock_motions(
    cleaned: list[Motion], inputs: list[Motion], body: BodyModel, feet: FootLockConfig
) -> list[Motion]:
    """The foot lock (``infer.feet.lock_feet``) on denoised motions, each with its input as
    the source; in a hole the lock reads the cleaned motion as the input's (and at the input's
    spikes in the legs where its feet are a goal: :func:`lock_feet`)."""
    sources = [holes_from(s, m) for m, s in zip(cleaned, inputs, strict=True)]
    return [lock_feet(m, body, feet, src) for m, src in zip(cleaned, sources, strict=True)]


#: the joints that place the feet: pelvis, hips, knees, ankles, feet
FOOT_CHAIN = [0, 1, 2, 4, 5, 7, 8, 10, 11]


def without_spikes(source: Motion) -> Motion:
    """``source`` with its spikes in :data:`FOOT_CHAIN` marked as holes (``joint_mask``), and
    the joints of the chain below each: the cleaned frame read there in its stead keeps them
    where the input had them in the world (``infer.spike_worlds``), which the input's own
    local rotations under the cleaned one would not (a pelvis spike filled under the input's
    hips, which had undone it, turned CMU 01_03's leg 6 degrees for a frame)."""
    spikes = source_spikes(source, FOOT_CHAIN)
    if not spikes.any():
        return source
    for j in FOOT_CHAIN[1:]:  # parents first
        spikes[:, j] |= spikes[:, int(SMPL_PARENTS[j])]
    marked = source.with_body()
    marked.joint_mask = observed(source) & ~spikes
    return marked

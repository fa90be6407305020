"""Random scenarios: a cloth hanging from a few moving pins in changing wind, seen by a camera
that stays put (`deform`), rolls about its optical axis from 0 to 180 degrees (`rotate`) or moves
back to twice its starting distance (`scale`; the cloth also drifts, so the image scale of the
last frame is 0.29-0.38, measured on 30-frame sequences). Lights, noise and all simulation
parameters are drawn from one seed.

Presets (`PRESETS`) set how hard the scenes are:
  * `mild`: the original scenes (cloth ~0.6 m wide at 0.85-1.05 m, pins moving a few cm).
  * `paper`: the paper's simulation section: the cloth fills 30-60 % of the frame, the camera of
    `deform` swings between 0.5x and 1.3x image scale, pins move and squeeze more, gusts.
  * `hard`: what real handling does: the cloth fills 40-80 % of the frame, pins squeeze the cloth
    into strong folds, abrupt gusts, the camera orbits the cloth (foreshortening up to ~70 deg),
    fast-moving lights with specular highlights, a plain back side, stronger image noise and
    (optional) motion blur.
  paper and hard also jitter the texture's colours and contrast (`textures.jitter_colours`).

World coordinates are the reference camera's: x right, y down (gravity), z forward, metres.
The reference frame (frame 0) shows the flat cloth before any simulation step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from ..inputs import check_bool, check_non_negative
from .cloth import Cloth, ClothConfig
from .noise import depth_noise_sigma, finish_image, kinect_depth_noise, motion_blur
from .render import RenderOutput, render
from .textures import jitter_colours, prepare_texture, texture_width

SCENARIOS = ("deform", "rotate", "scale")
#: Simulation steps of a 30-frame sequence at the default 6 steps per frame. paper and hard compress their
#: motion into shorter sequences; those get this many steps' worth of sub-steps (`ClothScene`).
PRESET_REF_STEPS = 29 * 6
#: Open interval of accepted vertical fields of view, degrees.
FOV_RANGE_DEG = (20.0, 120.0)


@dataclass(frozen=True)
class Preset:
    """How hard a scene is. Ranges are (low, high) drawn uniformly per sequence.

    Attributes:
        name: preset name.
        fill: fraction of the image area the flat reference cloth covers, on a frame of any shape (sets the
            camera distance, `fill_distance`); None = mild's distance draw (0.85-1.05 m).
        scale_swing: `deform` camera distance swings so that the image scale goes through this range
            (None = fixed camera).
        orbit_deg: the camera orbits the cloth centre by up to this yaw (and 0.6x this pitch).
        tilt_rad: largest rest tilt of the cloth about x and y.
        pin_amp: (3,) largest amplitude (x, y, z) of the pin motion, metres.
        squeeze: pins are drawn together by up to this fraction of their spread (folds).
        gust_rate: wind gusts per 100 simulation steps; gust_gain: their peak wind multiplier.
        wind_gain, gravity_gain: multipliers of mild's wind and gravity draws.
        light_speed: multiplier of mild's light drift rate; light_drift_m: drift amplitude, metres.
        ambient: ambient light range; specular: highlight strength range (0 = matte).
        image_sigma: pixel noise range, 8-bit grey levels.
        back_plain: the back side of the cloth is a plain colour (not the texture).
        blur_px: largest motion-blur length, pixels, when motion blur is on.
    """

    name: str
    fill: tuple[float, float] | None = None
    scale_swing: tuple[float, float] | None = None
    orbit_deg: float = 0.0
    tilt_rad: float = 0.15
    pin_amp: tuple[float, float, float] = (0.06, 0.03, 0.08)
    squeeze: float = 0.1
    gust_rate: float = 0.0
    gust_gain: float = 0.0
    wind_gain: float = 1.0
    gravity_gain: float = 1.0
    light_speed: float = 1.0
    light_drift_m: tuple[float, float] = (0.05, 0.3)
    ambient: tuple[float, float] = (0.15, 0.4)
    specular: tuple[float, float] = (0.0, 0.0)
    image_sigma: tuple[float, float] = (1.0, 4.0)
    back_plain: bool = False
    blur_px: float = 0.0

    def __post_init__(self) -> None:
        """ValueError naming the first field that cannot simulate (`check_preset`)."""
        check_preset(self)


#: Fields of `Preset` that are one number >= 0, and (low, high) ranges of numbers >= 0.
_PRESET_NUMBERS = ("orbit_deg", "tilt_rad", "gust_rate", "gust_gain", "wind_gain", "gravity_gain", "light_speed",
                   "blur_px")
_PRESET_RANGES = ("light_drift_m", "ambient", "specular", "image_sigma")


def check_preset(preset: Preset) -> None:
    """ValueError naming the first field of `preset` that cannot simulate: every number finite and
    >= 0, `squeeze` below 1 (1 draws the pins onto one point), each range (low, high) of two such
    numbers with low <= high (a 1-tuple was read as (low, 1.0)), `ambient` within 0..1, `fill` within
    (0, 1] (a fraction of the image area), `scale_swing` positive with low < high (equal ends divided
    by zero), `pin_amp` three numbers. A NaN wind or gravity gave NaN particles, written as frames
    without cloth that no command could read."""
    def number(v, what: str) -> float:
        return check_non_negative(v, f"preset: {what}")

    def numbers(value, what: str, count: int) -> tuple[float, ...]:
        if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or len(value) != count:
            raise ValueError(f"preset: {what}: expected {count} numbers, got {value!r}")
        return tuple(number(v, what) for v in value)

    def span(value, what: str) -> tuple[float, float]:
        lo, hi = numbers(value, what, 2)
        if lo > hi:
            raise ValueError(f"preset: {what}: expected (low, high) with low <= high, got {value!r}")
        return lo, hi

    if not isinstance(preset.name, str) or not preset.name:
        raise ValueError(f"preset: name: expected a non-empty string, got {preset.name!r}")
    for what in _PRESET_NUMBERS:
        number(getattr(preset, what), what)
    if number(preset.squeeze, "squeeze") >= 1:
        raise ValueError(f"preset: squeeze: expected a fraction below 1, got {preset.squeeze!r}")
    numbers(preset.pin_amp, "pin_amp", 3)
    for what in _PRESET_RANGES:
        span(getattr(preset, what), what)
    if span(preset.ambient, "ambient")[1] > 1:
        raise ValueError(f"preset: ambient: expected light levels within 0..1, got {preset.ambient!r}")
    if preset.fill is not None:
        lo, hi = span(preset.fill, "fill")
        if lo <= 0 or hi > 1:
            raise ValueError(f"preset: fill: expected fractions of the image area within (0, 1], got {preset.fill!r}")
    if preset.scale_swing is not None:
        lo, hi = span(preset.scale_swing, "scale_swing")
        if not 0 < lo < hi:
            raise ValueError(f"preset: scale_swing: expected image scales 0 < low < high (None: a fixed camera), "
                             f"got {preset.scale_swing!r}")
    check_bool(preset.back_plain, "preset: back_plain")


PRESETS: dict[str, Preset] = {
    "mild": Preset("mild"),
    "paper": Preset("paper", fill=(0.3, 0.6), scale_swing=(0.5, 1.3), orbit_deg=10.0, tilt_rad=0.2,
                    pin_amp=(0.08, 0.04, 0.10), squeeze=0.15, gust_rate=0.5, gust_gain=1.5, wind_gain=1.2,
                    light_speed=2.0, specular=(0.0, 0.15), back_plain=True, blur_px=3.0),
    "hard": Preset("hard", fill=(0.4, 0.8), scale_swing=(0.5, 1.3), orbit_deg=30.0, tilt_rad=0.3,
                   pin_amp=(0.12, 0.06, 0.15), squeeze=0.3, gust_rate=1.0, gust_gain=3.0, wind_gain=2.0,
                   gravity_gain=1.3, light_speed=4.0, light_drift_m=(0.2, 0.5), ambient=(0.05, 0.25),
                   specular=(0.1, 0.4), image_sigma=(2.0, 6.0), back_plain=True, blur_px=6.0),
}


def default_intrinsics(width: int = 640, height: int = 480, fov_deg: float | None = None) -> np.ndarray:
    """Centred (3, 3) intrinsics with square pixels: Kinect-like f = 525 px at 640 x 480 (scaled with
    the width; 49.1 deg vertical at 640 x 480), or the focal length giving `fov_deg` degrees of
    vertical field of view (the paper authors' renders: 90)."""
    if fov_deg is None:
        f = 525.0 * width / 640.0
    else:
        check_fov(fov_deg)
        # in float64: a numpy float32 fov gave another K than the fov_deg recorded (float) reproduces
        f = (height / 2.0) / np.tan(np.radians(float(fov_deg)) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def check_fov(fov_deg: float) -> None:
    """ValueError unless fov_deg is a number inside FOV_RANGE_DEG (open interval)."""
    lo, hi = FOV_RANGE_DEG
    if isinstance(fov_deg, bool) or not isinstance(fov_deg, (int, float, np.floating, np.integer)) \
            or not lo < float(fov_deg) < hi:
        raise ValueError(f"fov: expected a vertical field of view in degrees strictly between {lo:g} and {hi:g}, "
                         f"got {fov_deg!r}")


def fill_distance(fill: float, K: np.ndarray, size: tuple[int, int], cloth_size: tuple[float, float]) -> float:
    """Distance (metres) at which a flat cloth of `cloth_size` (width, height) metres, facing the camera
    K (3, 3) with its centre on the optical axis, covers the fraction `fill` of the (H, W) image's area.

    Where the whole cloth would then be taller than the image (a wide, short frame) or wider (a tall, narrow
    one), part of it is out of view (at 1280 x 320 a `fill` of 0.7 covered 0.48); there it comes closer,
    until the part in view covers `fill`: it spans the image's height (width) and `fill` of its width (height)."""
    H, W = size
    w, h = cloth_size
    d = float(np.sqrt(K[0, 0] * K[1, 1] * w * h / (fill * W * H)))  # the whole cloth in view
    if K[1, 1] * h / d > H:
        return float(K[0, 0] * w / (fill * W))
    if K[0, 0] * w / d > W:
        return float(K[1, 1] * h / (fill * H))
    return d


def get_preset(preset: str | Preset) -> Preset:
    """The Preset of a name (ValueError naming the choices) or the Preset itself."""
    if isinstance(preset, Preset):
        if preset.name == "mild" and preset != PRESETS["mild"]:
            # the name selects mild's own draws (`SceneParams.draw`), which ignored the changed fields
            raise ValueError("preset: a Preset named 'mild' takes mild's own settings and ignores its fields; give a "
                             f"changed preset another name (dataclasses.replace(..., name='...')), got {preset!r}")
        return preset
    if not isinstance(preset, str) or preset not in PRESETS:  # a list raised TypeError (unhashable)
        raise ValueError(f"preset: expected one of {', '.join(PRESETS)}, got {preset!r}")
    return PRESETS[preset]


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


@dataclass
class SceneParams:
    """Everything random about one sequence (drawn by `SceneParams.draw`). Lengths in metres,
    accelerations in m / time unit^2, angles in radians, angular rates in rad / step."""

    cloth_width: float
    distance: float
    tilt: np.ndarray  # (2,) rotation of the rest cloth about x and y
    gravity: float
    wind_dir: np.ndarray  # (3,) unit mean direction
    wind_strength: float
    wind_wobble: np.ndarray  # (4, 2) (rate, phase) of the x, y, z direction and strength changes
    wave: np.ndarray  # (4,) kx, ky (rad / m), phase rate, amplitude of the spatial modulation
    pin_cols: np.ndarray  # (P,) columns of the top row that are pinned
    pin_amp: np.ndarray  # (P, 3) amplitude of the pin motion
    pin_rate: np.ndarray  # (P, 3) angular rate of the pin motion
    pin_phase: np.ndarray  # (P, 3)
    lights: np.ndarray  # (L, 3) world positions
    light_power: np.ndarray  # (L,)
    light_drift: np.ndarray  # (L, 4) amplitude (m), rate, phase, power modulation
    ambient: float
    image_sigma: float
    background: np.ndarray  # (3,) BGR in [0, 1]
    steps_per_frame: int
    extras: dict = field(default_factory=dict)

    @classmethod
    def draw(cls, rng: np.random.Generator, steps_per_frame: int = 6) -> "SceneParams":
        n_pins = int(rng.integers(2, 5))
        n_lights = int(rng.integers(1, 4))
        wind_dir = np.array([rng.normal(0, 0.5), rng.normal(0, 0.3), rng.choice([-1.0, 1.0])])
        lights = np.stack([rng.uniform(-0.8, 0.8, n_lights), rng.uniform(-0.8, 0.5, n_lights),
                           rng.uniform(-0.3, 0.5, n_lights)], axis=1)
        return cls(
            cloth_width=float(rng.uniform(0.5, 0.7)),
            distance=float(rng.uniform(0.85, 1.05)),
            tilt=rng.uniform(-0.15, 0.15, 2),
            gravity=float(rng.uniform(0.00015, 0.0004)),
            wind_dir=wind_dir / np.linalg.norm(wind_dir),
            wind_strength=float(rng.uniform(0.00015, 0.0005)),
            wind_wobble=np.stack([rng.uniform(0.005, 0.025, 4), rng.uniform(0, 2 * np.pi, 4)], axis=1),
            wave=np.array([rng.uniform(-25, 25), rng.uniform(-25, 25), rng.uniform(0.02, 0.1), rng.uniform(0.3, 1.0)]),
            pin_cols=np.linspace(0, 1, n_pins),  # n_pins >= 2: both top corners and evenly between
            pin_amp=rng.uniform(0.0, 1.0, (n_pins, 3)) * np.array([0.06, 0.03, 0.08]),
            pin_rate=rng.uniform(0.005, 0.0125, (n_pins, 3)),
            pin_phase=rng.uniform(0, 2 * np.pi, (n_pins, 3)),
            lights=lights,
            light_power=rng.uniform(0.4, 0.9, n_lights) / np.sqrt(n_lights),
            light_drift=np.stack([rng.uniform(0.05, 0.3, n_lights), rng.uniform(0.01, 0.04, n_lights),
                                  rng.uniform(0, 2 * np.pi, n_lights), rng.uniform(0.05, 0.25, n_lights)], axis=1),
            ambient=float(rng.uniform(0.15, 0.4)),
            image_sigma=float(rng.uniform(1.0, 4.0)),
            background=rng.uniform(0.0, 0.25, 3),
            steps_per_frame=int(steps_per_frame),
        )


@dataclass
class SimFrame:
    """One generated frame.

    Attributes:
        index: frame number (0 = reference).
        image: (H, W, 3) uint8 BGR with lighting and pixel noise.
        depth: (H, W) float32 metres, 0 = background / hole (Kinect-like noise if enabled).
        render: the noise-free RenderOutput (exact depth and the (u, v) map).
        vertices: (rows, cols, 3) float64 particles in this frame's camera coordinates, metres.
        R, t: world-to-camera rotation (3, 3) and translation (3,) metres.
    """

    index: int
    image: np.ndarray
    depth: np.ndarray
    render: RenderOutput
    vertices: np.ndarray
    R: np.ndarray
    t: np.ndarray


class ClothScene:
    """A seeded random scenario; iterate `frames()` to simulate and render it.

    Args:
        scenario: one of SCENARIOS.
        n_frames: number of frames including the reference (>= 1).
        rng: random generator (all randomness of the scene comes from it).
        texture: (Ht, Wt, 3) uint8 BGR texture image.
        size: (H, W) image size, pixels.
        K: (3, 3) intrinsics (default: `default_intrinsics(W, H)`).
        kinect_noise: degrade the written depth with `kinect_depth_noise` (drawn from a child generator of
            rng: the cloth, lights, images and ground truth are those of the same scene without it).
        cloth_config: grid and solver settings (the width is overridden by the drawn one; a paper or hard
            sequence of fewer than PRESET_REF_STEPS steps multiplies the sub-steps, see `config`).
        steps_per_frame: simulation steps between two frames.
        preset: a name of PRESETS (or a Preset): how hard the scene is.
        motion_blur: blur each frame along a random direction, up to `preset.blur_px` pixels.
    """

    def __init__(
        self,
        scenario: str,
        n_frames: int,
        rng: np.random.Generator,
        texture: np.ndarray,
        size: tuple[int, int] = (480, 640),
        K: np.ndarray | None = None,
        kinect_noise: bool = False,
        cloth_config: ClothConfig = ClothConfig(),
        steps_per_frame: int = 6,
        preset: str | Preset = "mild",
        motion_blur: bool = False,
    ) -> None:
        if scenario not in SCENARIOS:
            raise ValueError(f"scenario: expected one of {', '.join(SCENARIOS)}, got {scenario!r}")
        self.preset = get_preset(preset)
        self.scenario = scenario
        self.n_frames = int(n_frames)
        self.rng = rng
        self.size = (int(size[0]), int(size[1]))
        self.K = default_intrinsics(self.size[1], self.size[0]) if K is None else np.asarray(K, dtype=np.float64)
        self.kinect_noise = kinect_noise
        # the depth noise has a generator of its own, a child of rng (spawning draws nothing from rng):
        # drawn from rng, it shifted every later draw, so --kinect-noise gave another cloth motion, lights
        # and image noise than the same seed without it (up to 2 cm per vertex by frame 2)
        self._depth_rng = rng.spawn(1)[0]
        self.motion_blur = bool(motion_blur)
        self.params = p = SceneParams.draw(rng, steps_per_frame)
        if self.preset.name != "mild":
            texture = self._draw_preset(texture, cloth_config)
        cfg = ClothConfig(**{**cloth_config.__dict__, "width_m": p.cloth_width})
        steps = (self.n_frames - 1) * p.steps_per_frame
        if self.preset.name != "mild" and 0 < steps < PRESET_REF_STEPS:
            # the preset fits its pin motion, squeeze and ramp into the sequence however short (`_draw_preset`):
            # with 12 sub-steps a 3-frame sequence stretched structural edges by 7-25 % (99th percentile), so
            # |uv| was no geodesic distance. The same motion in proportionally more, smaller sub-steps.
            cfg = ClothConfig(**{**cfg.__dict__, "substeps": cfg.substeps * -(-PRESET_REF_STEPS // steps)})
        self.config = cfg
        R0 = _rot("y", p.tilt[1]) @ _rot("x", p.tilt[0])
        centre = np.array([cfg.width_m / 2, cfg.height_m / 2, 0.0])
        origin = np.array([0.0, 0.0, p.distance]) - R0 @ centre
        self.cloth = Cloth(cfg, origin=origin, R=R0)
        top = np.round(p.pin_cols * (cfg.cols - 1)).astype(np.int64)
        self.pin_idx = top  # top row: index = c
        self.pin_rest = self.cloth.pos[self.pin_idx].copy()
        self.cloth.pin(self.pin_idx)
        # the cloth's width in pixels at its closest view
        px_width = self.K[0, 0] * cfg.width_m / p.distance * (1.3 if self.preset.scale_swing else 1.0)
        aspect = cfg.width_m / cfg.height_m
        self.texture = prepare_texture(texture, aspect, texture_width(px_width, aspect))
        self.step_count = 0

    def _draw_preset(self, texture: np.ndarray, cloth_config: ClothConfig) -> np.ndarray:
        """Redraw the parameters a non-mild preset changes (after mild's draws, same generator);
        returns the texture with its colours and contrast jittered."""
        p, pr, rng, (H, W) = self.params, self.preset, self.rng, self.size
        # the scene's grid: a default 60 x 80 one here set the distance for a cloth of another aspect
        # (a 20 x 80 grid filled a third of the `fill` asked for)
        cfg = ClothConfig(**{**cloth_config.__dict__, "width_m": p.cloth_width})
        if pr.fill is not None:
            p.distance = fill_distance(rng.uniform(*pr.fill), self.K, self.size, (cfg.width_m, cfg.height_m))
        d = p.distance
        p.tilt = rng.uniform(-pr.tilt_rad, pr.tilt_rad, 2)
        steps = max(1, (self.n_frames - 1) * p.steps_per_frame)
        n_pins = len(p.pin_cols)
        p.pin_amp = rng.uniform(0.0, 1.0, (n_pins, 3)) * np.asarray(pr.pin_amp)
        # pin motion: at least half a period within the sequence, however short it is
        p.pin_rate = np.maximum(p.pin_rate, rng.uniform(1.0, 2.5, p.pin_rate.shape) * np.pi / steps)
        p.gravity *= pr.gravity_gain
        p.wind_strength *= pr.wind_gain
        n_lights = len(p.lights)
        p.lights = np.stack([rng.uniform(-0.8, 0.8, n_lights) * d, rng.uniform(-0.8, 0.5, n_lights) * d,
                             rng.uniform(0.0, 0.7, n_lights) * d], axis=1)
        p.light_drift[:, 0] = rng.uniform(*pr.light_drift_m, n_lights) * d
        p.light_drift[:, 1] *= pr.light_speed
        p.ambient = float(rng.uniform(*pr.ambient))
        p.image_sigma = float(rng.uniform(*pr.image_sigma))
        n_gusts = int(rng.poisson(pr.gust_rate * steps / 100.0))
        gust_dir = rng.normal(0, 0.5, (n_gusts, 3))
        gust_dir[:, 2] = rng.choice([-1.0, 1.0], n_gusts)
        mean = texture.reshape(-1, 3).mean(axis=0) / 255.0
        grey = mean.mean()
        p.extras = {
            "squeeze": float(rng.uniform(0.5, 1.0) * pr.squeeze),
            "squeeze_rate": float(rng.uniform(1.0, 2.0) * np.pi / steps),
            "ramp_steps": 0.25 * steps,
            "gust_start": rng.uniform(0, steps, n_gusts),
            "gust_tau": rng.uniform(4.0, 25.0, n_gusts),
            "gust_gain": rng.uniform(0.5, 1.0, n_gusts) * pr.gust_gain,
            "gust_dir": gust_dir / np.linalg.norm(gust_dir, axis=1, keepdims=True),
            "swing_cycles": float(rng.uniform(0.75, 1.5)),
            "orbit": rng.uniform(0.5, 1.0, 2) * np.radians(pr.orbit_deg) * rng.choice([-1.0, 1.0], 2)
            * np.array([1.0, 0.6]),
            "orbit_cycles": rng.uniform(0.4, 1.2, 2),
            "specular": float(rng.uniform(*pr.specular)),
            "shininess": float(rng.uniform(10.0, 60.0)),
            "back_color": (0.5 * grey + 0.5 * mean) * rng.uniform(0.5, 0.9) if pr.back_plain else None,
        }
        return jitter_colours(np.ascontiguousarray(texture, dtype=np.uint8), rng)

    # ------------------------------------------------------------------ time-varying inputs
    def _wind(self, k: int) -> np.ndarray:
        p = self.params
        wob = np.sin(p.wind_wobble[:, 0] * k + p.wind_wobble[:, 1])
        d = p.wind_dir + 0.6 * wob[:3]
        wind = p.wind_strength * (0.55 + 0.45 * wob[3]) * d / np.linalg.norm(d)
        e = p.extras
        if len(e.get("gust_start", ())):
            dt = k - e["gust_start"]
            pulse = np.where(dt >= 0, np.exp(-np.maximum(dt, 0) / e["gust_tau"]), 0.0) * e["gust_gain"]
            wind = wind + p.wind_strength * (pulse[:, None] * e["gust_dir"]).sum(axis=0)
        return wind

    def _pins(self, k: int) -> np.ndarray:
        p = self.params
        ramp = min(1.0, k / p.extras.get("ramp_steps", 150.0))  # start from rest smoothly
        offset = p.pin_amp * (np.sin(p.pin_rate * k + p.pin_phase) - np.sin(p.pin_phase)) * ramp
        pins = self.pin_rest + offset
        # keep the pin set feasible with some slack: no two pins farther apart than 90 % of their
        # rest distance (a taut cloth cannot be held isometric by a few constraint sweeps)
        centre = pins.mean(axis=0)
        d = np.linalg.norm(pins[:, None] - pins[None], axis=2)
        rest = np.linalg.norm(self.pin_rest[:, None] - self.pin_rest[None], axis=2)
        # pairs of distinct pins (two pins on one particle of a narrow grid have rest 0: their scale was 0)
        off = ~np.eye(len(pins), dtype=bool) & (rest > 0)
        slack = 1.0 - 0.1 * ramp
        scale = min(1.0, float(np.min(slack * rest[off] / np.maximum(d[off], 1e-12)))) if off.any() else 1.0
        if "squeeze" in p.extras:  # draw the pins together (and apart again): folds between them
            scale *= 1.0 - p.extras["squeeze"] * ramp * (0.5 - 0.5 * np.cos(p.extras["squeeze_rate"] * k))
        return centre + (pins - centre) * scale

    def _camera(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        """World-to-camera (R, t) of frame f: X_cam = R X + t."""
        a = f / (self.n_frames - 1) if self.n_frames > 1 else 0.0
        d, e = self.params.distance, self.params.extras
        if self.preset.name == "mild":
            if self.scenario == "rotate":
                # roll about the ray through the cloth centre (on the optical axis)
                return _rot("z", np.pi * a), np.zeros(3)
            if self.scenario == "scale":
                return np.eye(3), np.array([0.0, 0.0, d * a])
            return np.eye(3), np.zeros(3)
        roll = np.pi * a if self.scenario == "rotate" else 0.0
        back = 0.0  # camera moved back along its axis, metres
        if self.scenario == "scale":
            back = d * a
        elif self.scenario == "deform" and self.preset.scale_swing is not None:
            lo, hi = self.preset.scale_swing
            mid, amp = (lo + hi) / 2, (hi - lo) / 2
            phi0 = np.arcsin(np.clip((1.0 - mid) / amp, -1, 1))  # image scale 1 at the reference
            s = mid + amp * np.sin(phi0 + 2 * np.pi * e["swing_cycles"] * a)
            back = d * (1.0 / s - 1.0)
        yaw, pitch = e["orbit"] * np.sin(np.pi * e["orbit_cycles"] * a)
        orbit = _rot("y", yaw) @ _rot("x", pitch)
        centre = np.array([0.0, 0.0, d])  # the cloth centre, on the reference optical axis
        R = _rot("z", roll) @ orbit
        return R, centre - R @ centre + np.array([0.0, 0.0, back])

    def depth_bound(self) -> float:
        """A depth (metres) that no frame of the sequence reaches, known before simulating (`simulate_sequence`
        chooses the depth PNGs' unit by it).

        Every frame's camera is known, and the cloth stays near its rest centre c: each pin within twice its
        motion amplitude of its rest place (pins drawn together stay between them), each free particle within
        its rest (u, v) distance of every pin (the tethers; 10 % added for what the last constraint sweep
        moves). A point's depth is at most c's plus that reach, plus 6 sigma of the depth noise."""
        cloth, p = self.cloth, self.params
        centre = np.array([0.0, 0.0, p.distance])  # the rest cloth's centre (`__init__`)
        pins = np.max(np.linalg.norm(self.pin_rest - centre, axis=1) + 2 * np.linalg.norm(p.pin_amp, axis=1))
        to_pin = np.linalg.norm(cloth.uv[:, None] - cloth.uv[self.pin_idx][None], axis=2).min(axis=1).max()
        reach = 1.1 * to_pin + pins
        far = max((R @ centre + t)[2] for R, t in map(self._camera, range(self.n_frames))) + reach
        return float(far + 6 * depth_noise_sigma(far)) if self.kinect_noise else float(far)

    def _lights(self, f: int) -> tuple[np.ndarray, np.ndarray]:
        p = self.params
        d = p.light_drift
        phase = d[:, 1] * self.step_count + d[:, 2]
        pos = p.lights + d[:, :1] * np.stack([np.sin(phase), np.cos(1.3 * phase), np.sin(0.7 * phase)], axis=1)
        power = p.light_power * (1 + d[:, 3] * np.sin(1.7 * phase))
        return pos, power

    # ------------------------------------------------------------------ simulation
    def _perturb(self) -> None:
        """Bend the flat cloth out of its plane by a smooth random bump (<= 3 mm) so that
        in-plane compression by the pins buckles it instead of straining it."""
        cfg = self.config
        uv = self.cloth.uv / np.array([cfg.width_m, cfg.height_m])
        k = self.rng.uniform(1.0, 3.0, 2) * np.pi
        phase = self.rng.uniform(0, 2 * np.pi, 2)
        bump = 0.003 * np.sin(k[0] * uv[:, 0] + phase[0]) * np.sin(k[1] * uv[:, 1] + phase[1])
        free = ~self.cloth.pinned
        self.cloth.pos[free] += bump[free, None] * self.cloth.normals()[free]
        self.cloth.prev[:] = self.cloth.pos

    def advance(self, steps: int) -> None:
        """Run `steps` simulation steps."""
        p = self.params
        if self.step_count == 0 and steps > 0:
            self._perturb()
        gravity = np.array([0.0, p.gravity, 0.0])
        for _ in range(steps):
            k = self.step_count
            self.cloth.pin_pos[self.pin_idx] = self._pins(k)
            wave_k = p.wave[:2]
            self.cloth.step(gravity, self._wind(k), wave_k, p.wave[2] * k, p.wave[3])
            self.step_count += 1

    def render_frame(self, f: int) -> SimFrame:
        """Render the current cloth state as frame `f` (camera and lights of frame f)."""
        R, t = self._camera(f)
        verts = self.cloth.pos @ R.T + t
        normals = self.cloth.normals() @ R.T
        lights, power = self._lights(f)
        e = self.params.extras
        out = render(verts, normals, self.cloth.uv, self.cloth.triangles, self.K, self.size, self.texture,
                     (self.config.width_m, self.config.height_m), lights @ R.T + t, power, self.params.ambient,
                     specular=e.get("specular", 0.0), shininess=e.get("shininess", 20.0),
                     back_color=e.get("back_color"))
        if self.motion_blur and self.preset.blur_px > 0 and f > 0:
            color = np.where(out.mask[..., None], out.color, self.params.background[None, None].astype(np.float32))
            color = motion_blur(color, self.rng.uniform(0, self.preset.blur_px), self.rng.uniform(0, np.pi))
            image = finish_image(color, np.ones_like(out.mask), self.params.background, self.params.image_sigma,
                                 self.rng)
        else:
            image = finish_image(out.color, out.mask, self.params.background, self.params.image_sigma, self.rng)
        depth = kinect_depth_noise(out.depth, out.cos_view, self._depth_rng) if self.kinect_noise else out.depth
        cfg = self.config
        return SimFrame(f, image, depth, out, verts.reshape(cfg.rows, cfg.cols, 3), R, t)

    def frames(self) -> Iterator[SimFrame]:
        """Yield the n_frames frames; the reference (0) is the flat rest cloth."""
        for f in range(self.n_frames):
            if f > 0:
                self.advance(self.params.steps_per_frame)
            yield self.render_frame(f)

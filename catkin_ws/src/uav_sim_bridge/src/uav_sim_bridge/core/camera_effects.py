"""What a real camera does to the rendered image: a pure, seeded numpy/OpenCV stage after rendering.

The stage follows the light through a camera, in this order:

1. **defocus** (the lens): each pixel is blurred by its circle of confusion,
   ``c = aperture * fx * |1/z - 1/focus|`` pixels (thin lens; ``fx`` in pixels), from the depth
   image; the image is blurred at a few levels and each pixel blends the two levels around its ``c``;
2. **motion blur** (the exposure): the camera's own motion during the exposure time moves every
   static point across the image (the motion field of the camera's linear and angular velocity,
   with the depth image for the parallax); each pixel averages the image along its streak: one line
   kernel when the whole frame moves alike, else one per tile of a 4 x 4 grid (the tile's mean streak);
3. **exposure, gain and vignetting**: the image as rendered is what the camera records at
   ``reference_exposure_s`` and gain 1; a longer exposure or a higher gain brightens it, the
   corners darken by ``vignetting`` (cos^4-like fall-off). Auto-exposure measures the mean
   luminance and moves exposure (first, up to ``max_exposure_s``) and gain (then, up to
   ``max_gain``) towards ``target`` at ``adapt_per_s`` (simulation time; it starts adapted);
4. **sensor noise**: shot noise (Poisson, as Gaussian with variance = electrons; ``full_well_e``
   electrons fill the scale at gain 1) and read noise (``read_noise_e``), both amplified by the
   gain, then clipping and 8-bit quantisation;
5. **JPEG** compression at ``jpeg_quality`` (encoded and decoded, so its artefacts are in the image).

Dropped frames and latency are the engine's (``drop_probability`` is drawn here, before the frame
is rendered; ``latency_s`` delays publication).

Determinism: each camera has its own generator (seeded from the environment's seed and the camera
name) and draws the same numbers in the same order for the same frames, so a lockstep run is
reproduced exactly. Gaussian noise is taken from a bank of normals drawn once per camera at a
random offset per frame (a fresh 640x480x3 draw would cost more than the render).

With nothing configured (:attr:`CameraEffectsConfig.active` false) the stage is not run at all.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "CameraEffects",
    "CameraEffectsConfig",
    "CameraMotion",
    "DefocusConfig",
    "EffectsResult",
    "ExposureConfig",
    "SensorNoiseConfig",
    "camera_rng",
    "motion_field_px",
]

FloatArray = npt.NDArray[np.float32]
_BANK_PAD = 64  # rows of normals beyond one frame in the noise bank
_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float32)


@dataclass(frozen=True)
class ExposureConfig:
    """Exposure time and gain: fixed, or automatic (``auto``) within the limits."""

    auto: bool = True
    exposure_s: float = 0.004
    reference_exposure_s: float = 0.004
    min_exposure_s: float = 0.0001
    max_exposure_s: float = 0.02
    max_gain: float = 8.0
    target: float = 0.42
    adapt_per_s: float = 3.0

    def __post_init__(self) -> None:
        if not 0 < self.min_exposure_s <= self.exposure_s <= self.max_exposure_s <= 1.0:
            msg = (
                "exposure needs 0 < min_exposure_s <= exposure_s <= max_exposure_s <= 1 s, got "
                f"{self.min_exposure_s}, {self.exposure_s}, {self.max_exposure_s}"
            )
            raise ValueError(msg)
        if not self.reference_exposure_s > 0 or not self.max_gain >= 1.0:
            msg = "reference_exposure_s must be > 0 and max_gain >= 1"
            raise ValueError(msg)
        if not 0.02 <= self.target <= 0.9 or not self.adapt_per_s > 0:
            msg = f"target must be in [0.02, 0.9] and adapt_per_s > 0, got {self.target}, {self.adapt_per_s}"
            raise ValueError(msg)


@dataclass(frozen=True)
class SensorNoiseConfig:
    """Shot noise from ``full_well_e`` electrons at full scale (gain 1) and read noise in electrons."""

    full_well_e: float = 6000.0
    read_noise_e: float = 3.0

    def __post_init__(self) -> None:
        if not self.full_well_e >= 50.0 or not self.read_noise_e >= 0.0:
            msg = f"full_well_e must be >= 50 and read_noise_e >= 0, got {self.full_well_e}, {self.read_noise_e}"
            raise ValueError(msg)


@dataclass(frozen=True)
class DefocusConfig:
    """A thin lens focused at ``focus_distance_m`` with an aperture of ``aperture_mm``."""

    focus_distance_m: float = 30.0
    aperture_mm: float = 4.0

    def __post_init__(self) -> None:
        if not self.focus_distance_m > 0 or not 0 < self.aperture_mm <= 100:
            msg = (
                f"focus_distance_m must be > 0 and aperture_mm in (0, 100], got {self.focus_distance_m}, "
                f"{self.aperture_mm}"
            )
            raise ValueError(msg)


@dataclass(frozen=True)
class CameraEffectsConfig:
    """One camera's effects; each is off when left out (``None``, ``false`` or 0)."""

    exposure: ExposureConfig | None = None
    noise: SensorNoiseConfig | None = None
    motion_blur: bool = False
    defocus: DefocusConfig | None = None
    vignetting: float = 0.0
    jpeg_quality: int | None = None
    drop_probability: float = 0.0
    latency_s: float = 0.0

    def __post_init__(self) -> None:
        if self.motion_blur and self.exposure is None:
            msg = "motion_blur needs an exposure section (the blur lasts the exposure time)"
            raise ValueError(msg)
        if not 0.0 <= self.vignetting <= 0.9:
            msg = f"vignetting must be in [0, 0.9] (corner darkening), got {self.vignetting}"
            raise ValueError(msg)
        if self.jpeg_quality is not None and not 5 <= self.jpeg_quality <= 100:
            msg = f"jpeg_quality must be in [5, 100] or null, got {self.jpeg_quality}"
            raise ValueError(msg)
        if not 0.0 <= self.drop_probability < 1.0:
            msg = f"drop_probability must be in [0, 1), got {self.drop_probability}"
            raise ValueError(msg)
        if not 0.0 <= self.latency_s <= 5.0:
            msg = f"latency_s must be in [0, 5] s, got {self.latency_s}"
            raise ValueError(msg)

    @property
    def changes_pixels(self) -> bool:
        """Whether the stage changes the image (dropping and delaying frames do not)."""
        return (
            self.exposure is not None
            or self.noise is not None
            or self.defocus is not None
            or self.vignetting > 0.0
            or self.jpeg_quality is not None
        )

    @property
    def active(self) -> bool:
        return self.changes_pixels or self.drop_probability > 0.0 or self.latency_s > 0.0


@dataclass(frozen=True)
class CameraMotion:
    """The camera's velocity in its optical frame (x right, y down, z forward): m/s and rad/s."""

    linear_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_rps: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class EffectsResult:
    """The camera's image and the settings it was taken with."""

    color_rgb: npt.NDArray[np.uint8]
    exposure_s: float
    gain: float
    blur_px: float  # longest motion-blur streak in the frame


def camera_rng(seed: int, camera: str) -> np.random.Generator:
    """The effects' generator of one camera: independent of the other cameras and of their order."""
    return np.random.default_rng([int(seed), zlib.crc32(camera.encode())])


def motion_field_px(  # noqa: PLR0917 - the intrinsics are four numbers
    depth_m: npt.NDArray[np.float32],
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    motion: CameraMotion,
    duration_s: float,
    step: int = 4,
    *,
    full: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Image motion ``(du, dv)`` in pixels of every static point over ``duration_s`` (full resolution).

    The classic motion field of a camera moving with linear velocity ``v`` and angular velocity ``w``
    (optical frame) seeing a point at depth ``z``: translation divided by depth plus rotation. Computed
    on every ``step``-th pixel and interpolated (smooth except at depth edges); ``full=False`` returns the
    coarse grid itself.
    """
    h, w = depth_m.shape
    z = depth_m[::step, ::step].astype(np.float32)
    inv_z = np.where(np.isfinite(z) & (z > 0), 1.0 / np.maximum(z, 1e-3), 0.0).astype(np.float32)
    rows = np.arange(0, h, step, dtype=np.float32)
    cols = np.arange(0, w, step, dtype=np.float32)
    x = ((cols - cx) / fx)[None, :]
    y = ((rows - cy) / fy)[:, None]
    vx, vy, vz = (float(v) for v in motion.linear_mps)
    wx, wy, wz = (float(v) for v in motion.angular_rps)
    du = fx * ((x * vz - vx) * inv_z + x * y * wx - (1.0 + x * x) * wy + y * wz) * duration_s
    dv = fy * ((y * vz - vy) * inv_z + (1.0 + y * y) * wx - x * y * wy - x * wz) * duration_s
    du = np.ascontiguousarray(du, dtype=np.float32)
    dv = np.ascontiguousarray(dv, dtype=np.float32)
    if not full:
        return du, dv
    return (
        np.asarray(cv2.resize(du, (w, h), interpolation=cv2.INTER_LINEAR), dtype=np.float32),
        np.asarray(cv2.resize(dv, (w, h), interpolation=cv2.INTER_LINEAR), dtype=np.float32),
    )


@dataclass
class _ExposureState:
    exposure_s: float
    gain: float
    last_t_s: float | None = None


@dataclass
class CameraEffects:
    """The stateful effects stage of one camera (auto-exposure and the random stream carry over frames).

    Args:
        cfg: the camera's effects.
        width, height: image size.
        fx, fy, cx, cy: intrinsics (pixels), for defocus and motion blur.
        rng: the camera's generator (:func:`camera_rng`).
    """

    cfg: CameraEffectsConfig
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    rng: np.random.Generator
    _exposure: _ExposureState | None = field(default=None, init=False)
    _vignette: FloatArray | None = field(default=None, init=False)
    _bank: FloatArray | None = field(default=None, init=False)
    _grid: tuple[FloatArray, FloatArray] | None = field(default=None, init=False)
    _drop_rng: np.random.Generator | None = field(default=None, init=False)

    def __post_init__(self) -> None:
        # drops are decided before a frame renders, possibly while the previous frame's effects still run in the
        # effects thread: their own stream (spawned, so ``rng``'s draws are unchanged) keeps both deterministic
        self._drop_rng = self.rng.spawn(1)[0]
        e = self.cfg.exposure
        if e is not None:
            self._exposure = _ExposureState(e.exposure_s, 1.0)
        if self.cfg.vignetting > 0.0:
            rows = (np.arange(self.height, dtype=np.float32) - self.cy) / self.fy
            cols = (np.arange(self.width, dtype=np.float32) - self.cx) / self.fx
            r2 = rows[:, None] ** 2 + cols[None, :] ** 2
            fall = 1.0 / (1.0 + r2) ** 2  # cos^4 of the angle off the axis
            corner = float(fall.min())
            # scale the fall-off so the corners lose exactly `vignetting`
            v = 1.0 - (1.0 - fall) * (self.cfg.vignetting / max(1.0 - corner, 1e-6))
            self._vignette = np.ascontiguousarray(np.repeat(v[:, :, None], 3, axis=2), dtype=np.float32)
        if self.cfg.noise is not None:
            # one long run of normals; each frame takes a window of it at a random offset (contiguous: no copy)
            n = self.height * self.width * 3
            self._bank = self.rng.standard_normal(n + _BANK_PAD * self.width * 3, dtype=np.float32)

    # ---------------------------------------------------------------------------------------- per frame
    def drop(self) -> bool:
        """Whether this frame is lost (drawn every frame, before rendering, whatever the answer)."""
        assert self._drop_rng is not None
        u = float(self._drop_rng.random())
        return u < self.cfg.drop_probability

    def apply(
        self,
        color_rgb: npt.NDArray[np.uint8],
        depth_m: npt.NDArray[np.float32],
        t_s: float,
        motion: CameraMotion | None = None,
    ) -> EffectsResult:
        """The camera's image of a rendered frame at simulation time ``t_s``."""
        cfg = self.cfg
        exposure_s, gain = self._expose(color_rgb, t_s)
        if not cfg.changes_pixels:
            return EffectsResult(color_rgb, exposure_s, gain, 0.0)
        img = color_rgb
        if cfg.defocus is not None:
            img = self._defocus(img, depth_m, cfg.defocus)
        blur_px = 0.0
        if cfg.motion_blur and motion is not None:
            img, blur_px = self._motion_blur(img, depth_m, motion, exposure_s)
        # exposure x gain x vignetting, sensor noise, 8-bit quantisation: a few OpenCV passes
        scale = exposure_s / cfg.exposure.reference_exposure_s * gain if cfg.exposure is not None else 1.0
        if cfg.noise is not None and self._bank is not None:
            img = self._expose_with_noise(img, cfg.noise, scale, exposure_s, gain)
        elif self._vignette is not None:
            img = _u8(cv2.multiply(img, self._vignette, scale=scale, dtype=cv2.CV_8U))
        elif scale != 1.0:
            img = _u8(cv2.convertScaleAbs(img, alpha=scale))
        if cfg.jpeg_quality is not None:
            img = _jpeg(img, cfg.jpeg_quality)
        if img is color_rgb:
            img = color_rgb.copy()
        return EffectsResult(np.ascontiguousarray(img), exposure_s, gain, blur_px)

    # ---------------------------------------------------------------------------------------- stages
    def _expose(self, color_rgb: npt.NDArray[np.uint8], t_s: float) -> tuple[float, float]:
        e = self.cfg.exposure
        st = self._exposure
        if e is None or st is None:
            return 0.0, 1.0
        if not e.auto:
            return e.exposure_s, 1.0
        # luminance the camera would record now (from the rendered image at the reference exposure)
        sample = color_rgb[::8, ::8].astype(np.float32)
        mean = float((sample @ _LUMA).mean()) / 255.0
        k_now = st.exposure_s * st.gain / e.reference_exposure_s
        lo = e.min_exposure_s / e.reference_exposure_s
        hi = e.max_exposure_s * e.max_gain / e.reference_exposure_s
        k_want = min(hi, max(lo, e.target / max(mean, 1e-4)))
        if st.last_t_s is None:
            k = k_want  # the camera starts adapted
        else:
            dt = max(0.0, t_s - st.last_t_s)
            a = 1.0 - math.exp(-e.adapt_per_s * dt)
            k = math.exp(math.log(k_now) + a * (math.log(k_want) - math.log(k_now)))
        st.last_t_s = t_s
        exposure = min(e.max_exposure_s, max(e.min_exposure_s, k * e.reference_exposure_s))
        st.exposure_s = exposure
        st.gain = min(e.max_gain, max(1.0, k * e.reference_exposure_s / exposure))
        return st.exposure_s, st.gain

    def _defocus(
        self, img: npt.NDArray[np.uint8], depth_m: npt.NDArray[np.float32], d: DefocusConfig
    ) -> npt.NDArray[np.uint8]:
        k = d.aperture_mm * 1e-3 * self.fx

        def coc(z: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
            zz = np.where(np.isfinite(z), z, np.float32(1e6))
            return np.asarray(k * np.abs(1.0 / np.maximum(zz, 1e-3) - 1.0 / d.focus_distance_m), dtype=np.float32)

        if float(coc(depth_m[::8, ::8]).max()) < 0.75:  # the whole frame is sharp: nothing to do
            return img
        c = coc(depth_m)
        top = float(c.max())
        # blur levels (circle of confusion in pixels), each pixel blends the two around its own
        levels = [0.0] + [lv for lv in (1.5, 3.0, 6.0, 12.0) if lv < top] + [min(top, 24.0)]
        blurred = [img.astype(np.float32)] + [
            cv2.GaussianBlur(img, (0, 0), sigmaX=0.42 * lv).astype(np.float32) for lv in levels[1:]
        ]
        c = np.clip(c, 0.0, levels[-1])
        out = blurred[0]
        for i in range(1, len(levels)):
            lo, hi = levels[i - 1], levels[i]
            w = np.clip((c - lo) / max(hi - lo, 1e-6), 0.0, 1.0)[:, :, None]
            out = np.where(c[:, :, None] > lo, out * (1.0 - w) + blurred[i] * w, out)
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)

    def _motion_blur(
        self, img: npt.NDArray[np.uint8], depth_m: npt.NDArray[np.float32], motion: CameraMotion, exposure_s: float
    ) -> tuple[npt.NDArray[np.uint8], float]:
        du, dv = motion_field_px(depth_m, self.fx, self.fy, self.cx, self.cy, motion, exposure_s, step=8, full=False)
        streak = float(np.sqrt(np.max(du * du + dv * dv)))
        if streak < 0.5:  # less than half a pixel anywhere: invisible
            return img, streak
        mu, mv = float(du.mean()), float(dv.mean())
        if float(np.max(np.hypot(du - mu, dv - mv))) < 0.35:
            # the whole frame moves alike (flat ground, no rotation about the axis): one line kernel is exact
            return _line_blur(img, mu, mv), streak
        # otherwise tile by tile (4 x 4), each with its own streak: within a tile the field varies by well under a
        # pixel at the speeds and exposures where blur shows, and a tile's kernel reads across its edges (no seams)
        return _tiled_line_blur(img, du, dv), streak

    def _expose_with_noise(
        self, img: npt.NDArray[np.uint8], n: SensorNoiseConfig, scale: float, exposure_s: float, gain: float
    ) -> npt.NDArray[np.uint8]:
        assert self._bank is not None
        size = self.height * self.width * 3
        start = int(self.rng.integers(len(self._bank) - size + 1))
        normals = self._bank[start : start + size].reshape(self.height, self.width, 3)
        signal = (
            cv2.multiply(img, self._vignette, scale=scale, dtype=cv2.CV_32F)
            if self._vignette is not None
            else img.astype(np.float32) * np.float32(scale)
        )
        # noise std per rendered value (before vignetting), in output units: sqrt(electrons + read^2) / full
        # well * 255, times the gain; the exposure scales the electrons (shot noise), not the read noise
        per_dn = n.full_well_e / 255.0
        expo = scale / gain
        values = np.arange(256, dtype=np.float32)
        lut = np.sqrt(values * expo * per_dn + n.read_noise_e**2) / per_dn * gain
        std = cv2.LUT(img, lut.astype(np.float32).reshape(256, 1))
        return _u8(cv2.add(signal, cv2.multiply(std, normals), dtype=cv2.CV_8U))


def _jpeg(rgb: npt.NDArray[np.uint8], quality: int) -> npt.NDArray[np.uint8]:
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
        msg = "JPEG encoding failed"
        raise RuntimeError(msg)
    return _u8(cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB))


def _line_blur(img: npt.NDArray[np.uint8], du: float, dv: float) -> npt.NDArray[np.uint8]:
    """The image averaged along a straight streak ``(du, dv)`` pixels long, centred on each pixel."""
    length = math.hypot(du, dv)
    size = 2 * math.ceil(length / 2.0) + 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    n = max(2, math.ceil(length * 4))
    for k in range(n):  # a line drawn with sub-pixel weights (bilinear splats)
        t = k / (n - 1) - 0.5
        x, y = c + t * du, c + t * dv
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        for xx, yy, wgt in ((x0, y0, (1 - fx) * (1 - fy)), (x0 + 1, y0, fx * (1 - fy)), (x0, y0 + 1, (1 - fx) * fy),
                            (x0 + 1, y0 + 1, fx * fy)):  # fmt: skip
            if 0 <= xx < size and 0 <= yy < size:
                kernel[yy, xx] += wgt
    kernel /= kernel.sum()
    return _u8(cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT))


def _tiled_line_blur(
    img: npt.NDArray[np.uint8], du: FloatArray, dv: FloatArray, tiles: int = 4
) -> npt.NDArray[np.uint8]:
    """:func:`_line_blur` per tile of a ``tiles`` x ``tiles`` grid, with each tile's mean streak from the coarse
    motion field ``(du, dv)``."""
    h, w = img.shape[:2]
    gh, gw = du.shape
    out = img.copy()
    for ty in range(tiles):
        for tx in range(tiles):
            y0, y1 = h * ty // tiles, h * (ty + 1) // tiles
            x0, x1 = w * tx // tiles, w * (tx + 1) // tiles
            cy0, cy1 = gh * ty // tiles, max(gh * (ty + 1) // tiles, gh * ty // tiles + 1)
            cx0, cx1 = gw * tx // tiles, max(gw * (tx + 1) // tiles, gw * tx // tiles + 1)
            mu, mv = float(du[cy0:cy1, cx0:cx1].mean()), float(dv[cy0:cy1, cx0:cx1].mean())
            if math.hypot(mu, mv) < 0.5:
                continue
            m = math.ceil(math.hypot(mu, mv) / 2.0) + 1  # the kernel's reach beyond the tile
            a0, a1, b0, b1 = max(0, y0 - m), min(h, y1 + m), max(0, x0 - m), min(w, x1 + m)
            blurred = _line_blur(np.ascontiguousarray(img[a0:a1, b0:b1]), mu, mv)
            out[y0:y1, x0:x1] = blurred[y0 - a0 : y1 - a0, x0 - b0 : x1 - b0]
    return out


def _u8(img: object) -> npt.NDArray[np.uint8]:
    """An OpenCV result as the uint8 array it is."""
    return np.asarray(img, dtype=np.uint8)

"""Sun, sky and atmosphere: where the sun is and what light the renderer uses (pure).

* :func:`sun_position` — solar azimuth and elevation from the local solar time, the day of the
  year and the latitude (NOAA's low-precision formulas: declination from the fractional year;
  good to a few tenths of a degree, far below what a rendered shadow shows).
* :func:`lighting_for` — an :class:`~uav_sim_bridge.core.environment.EnvironmentConfig` ->
  :class:`Lighting`: sun direction and colour (reddened by the air mass it crosses), sky
  light, the sky's zenith, horizon and glow colours, haze/fog, overcast and shadows.

Calibration: at a clear sun 55 degrees up the light is exactly the renderer's original
look (sun 0.78, sky 0.34, ambient 0.06, white; haze towards (0.74, 0.80, 0.88) over an
1800 m scale, at most 55 %), which is the ``clean`` environment; lower suns are dimmer and
warmer, the sky darker, and below the horizon only twilight sky light is left (down to
-6 degrees, civil twilight). Overcast dims and greys the sun and the sky and evens out
the sky light; fog (``visibility_m``) follows Koschmieder (extinction 3.912 / visibility).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from uav_sim_bridge.core.environment import EnvironmentConfig

__all__ = ["CLEAN_HAZE_RGB", "Lighting", "lighting_for", "sun_direction", "sun_position"]

Rgb = tuple[float, float, float]

CLEAN_HAZE_RGB: Rgb = (0.74, 0.80, 0.88)
_CLEAN_ZENITH: Rgb = (0.30, 0.50, 0.82)
_CLEAN_SUN, _CLEAN_SKY, _CLEAN_AMBIENT = 0.78, 0.34, 0.06
_REF_ELEVATION_DEG = 55.0
# Optical depth of the clear atmosphere per channel (Rayleigh plus a little aerosol): reddens a low sun.
_TAU = np.array([0.09, 0.17, 0.33])
_OVERCAST_GREY = np.array([0.66, 0.68, 0.70])


def sun_position(time_of_day_h: float, day_of_year: int, latitude_deg: float) -> tuple[float, float]:
    """``(azimuth_deg clockwise from north, elevation_deg)`` of the sun at local solar time ``time_of_day_h``.

    Raises:
        ValueError: time outside [0, 24), day outside 1..366, latitude outside [-90, 90].
    """
    if not 0.0 <= time_of_day_h < 24.0:
        msg = f"time_of_day_h must be in [0, 24) (local solar time, hours), got {time_of_day_h}"
        raise ValueError(msg)
    if not 1 <= day_of_year <= 366:
        msg = f"day_of_year must be in 1..366, got {day_of_year}"
        raise ValueError(msg)
    if not -90.0 <= latitude_deg <= 90.0:
        msg = f"latitude_deg must be in [-90, 90], got {latitude_deg}"
        raise ValueError(msg)
    g = 2.0 * math.pi / 365.0 * (day_of_year - 1 + (time_of_day_h - 12.0) / 24.0)
    decl = (
        0.006918
        - 0.399912 * math.cos(g)
        + 0.070257 * math.sin(g)
        - 0.006758 * math.cos(2 * g)
        + 0.000907 * math.sin(2 * g)
        - 0.002697 * math.cos(3 * g)
        + 0.00148 * math.sin(3 * g)
    )
    lat = math.radians(latitude_deg)
    hour = math.radians(15.0 * (time_of_day_h - 12.0))
    sin_el = math.sin(lat) * math.sin(decl) + math.cos(lat) * math.cos(decl) * math.cos(hour)
    el = math.asin(max(-1.0, min(1.0, sin_el)))
    # azimuth from north, clockwise (east = 90): atan2 of the east and north components of the sun vector
    east = -math.cos(decl) * math.sin(hour)
    north = math.cos(lat) * math.sin(decl) - math.sin(lat) * math.cos(decl) * math.cos(hour)
    az = math.degrees(math.atan2(east, north)) % 360.0
    return az, math.degrees(el)


def sun_direction(azimuth_deg: float, elevation_deg: float) -> tuple[float, float, float]:
    """Unit vector towards the sun in ``map`` (x east, y north, z up)."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el))


@dataclass(frozen=True)
class Lighting:
    """Everything the renderer's shaders need about light and air.

    Attributes:
        sun_dir: unit vector towards the sun (map).
        sun_rgb: direct sun light on a surface facing it.
        sky_rgb: sky light on an upward surface (half of it on a vertical one).
        ambient_rgb: light from everywhere (bounce).
        zenith_rgb, horizon_rgb: the sky's colour straight up and at the horizon.
        glow_rgb: extra sky colour around the sun (dawn and dusk).
        haze_rgb: colour distant surfaces fade to.
        haze_per_m: extinction coefficient (1/m) of the fade.
        haze_max: the most a surface fades (1 = fog hides it completely).
        shadows: whether surfaces are shadowed from the sun.
        sun_disc: brightness of the sun's disc in the sky.
        azimuth_deg, elevation_deg: the sun's position (for people and reports).
    """

    sun_dir: tuple[float, float, float]
    sun_rgb: Rgb
    sky_rgb: Rgb
    ambient_rgb: Rgb
    zenith_rgb: Rgb
    horizon_rgb: Rgb
    glow_rgb: Rgb
    haze_rgb: Rgb
    haze_per_m: float
    haze_max: float
    shadows: bool
    sun_disc: float
    azimuth_deg: float
    elevation_deg: float

    @staticmethod
    def clean(azimuth_deg: float = 135.0, elevation_deg: float = 55.0, haze_distance_m: float = 1800.0) -> Lighting:
        """The renderer's original look: white sun and sky light, blue sky, light haze, no shadows."""
        s, k, a = _CLEAN_SUN, _CLEAN_SKY, _CLEAN_AMBIENT
        return Lighting(
            sun_dir=sun_direction(azimuth_deg, elevation_deg),
            sun_rgb=(s, s, s),
            sky_rgb=(k, k, k),
            ambient_rgb=(a, a, a),
            zenith_rgb=_CLEAN_ZENITH,
            horizon_rgb=CLEAN_HAZE_RGB,
            glow_rgb=(0.0, 0.0, 0.0),
            haze_rgb=CLEAN_HAZE_RGB,
            haze_per_m=1.0 / haze_distance_m,
            haze_max=0.55,
            shadows=False,
            sun_disc=1.0,
            azimuth_deg=azimuth_deg,
            elevation_deg=elevation_deg,
        )


def _air_mass(elevation_deg: float) -> float:
    """Kasten and Young's relative air mass (finite at the horizon)."""
    e = max(elevation_deg, -0.5)
    return float(1.0 / (math.sin(math.radians(e)) + 0.50572 * (e + 6.07995) ** -1.6364))


def _smoothstep(e0: float, e1: float, x: float) -> float:
    t = min(1.0, max(0.0, (x - e0) / (e1 - e0)))
    return t * t * (3.0 - 2.0 * t)


def _rgb(v: npt.NDArray[np.float64]) -> Rgb:
    c = np.clip(v, 0.0, 4.0)
    return (float(c[0]), float(c[1]), float(c[2]))


def lighting_for(env: EnvironmentConfig, latitude_deg: float, haze_distance_m: float = 1800.0) -> Lighting:
    """The light of an environment at a latitude (used when ``env.latitude_deg`` is None).

    The ``clean`` environment (no time of day, sun given by angles, no overcast, default haze)
    gives exactly :meth:`Lighting.clean`.

    Raises:
        ValueError: the sun is more than 6 degrees below the horizon (night is not simulated).
    """
    if env.time_of_day_h is None:
        az, el = env.sun_azimuth_deg, env.sun_elevation_deg
    else:
        lat = env.latitude_deg if env.latitude_deg is not None else latitude_deg
        az, el = sun_position(env.time_of_day_h, env.day_of_year, lat)
    if el < -6.0:
        msg = (
            f"the sun is {el:.1f} degrees below the horizon at time_of_day_h {env.time_of_day_h} on day "
            f"{env.day_of_year}: night is not simulated; choose a time between civil dawn and dusk"
        )
        raise ValueError(msg)
    physical = env.time_of_day_h is not None or env.overcast > 0.0 or env.visibility_m is not None
    if not physical and el == _REF_ELEVATION_DEG:
        base = Lighting.clean(az, el, haze_distance_m)
        return base if not env.shadows else _with(base, shadows=True)
    # Direct sun: extinction along the air mass, relative to the reference elevation (white there).
    trans = np.exp(-_TAU * _air_mass(el)) / np.exp(-_TAU * _air_mass(_REF_ELEVATION_DEG))
    above = _smoothstep(-0.8, 2.0, el)  # the disc sets over the last couple of degrees
    sun = _CLEAN_SUN * trans * above
    # Sky light: grows with the sun (twilight keeps a little), bluer in the day, warmer at dusk.
    day = _smoothstep(-6.0, 35.0, el)
    sky_level = _CLEAN_SKY * (0.12 + 0.88 * day**0.8) / 1.0
    warm = 1.0 - _smoothstep(0.0, 20.0, el)
    sky_tint = np.array([1.0, 1.0, 1.0]) * (1 - warm) + np.array([1.05, 0.92, 0.85]) * warm
    sky = sky_level * sky_tint
    ambient = _CLEAN_AMBIENT * (0.25 + 0.75 * day) * np.ones(3)
    zenith = np.array(_CLEAN_ZENITH) * (0.18 + 0.82 * day)
    zenith = zenith * (1 - 0.5 * warm) + np.array([0.20, 0.24, 0.45]) * 0.5 * warm * (0.3 + 0.7 * day)
    horizon = np.array(CLEAN_HAZE_RGB) * (0.25 + 0.75 * day)
    glow = np.array([1.0, 0.45, 0.15]) * 0.55 * warm * (0.25 + 0.75 * _smoothstep(-6.0, 1.0, el))
    oc = env.overcast
    if oc > 0.0:
        sun = sun * (1.0 - 0.9 * oc)
        grey_level = 0.45 + 0.55 * day
        sky = sky * (1.0 - oc) + _OVERCAST_GREY * (_CLEAN_SKY * 1.35) * grey_level * oc
        ambient = ambient * (1.0 + 0.8 * oc)
        zenith = zenith * (1.0 - oc) + _OVERCAST_GREY * 0.92 * grey_level * oc
        horizon = horizon * (1.0 - oc) + _OVERCAST_GREY * 0.98 * grey_level * oc
        glow = glow * (1.0 - oc)
    if env.visibility_m is None:
        haze_per_m, haze_max = 1.0 / haze_distance_m, 0.55
        haze = horizon
    else:
        haze_per_m, haze_max = 3.912 / env.visibility_m, 1.0
        # thin haze takes the horizon's colour; fog (visibility of a few km and less) scatters all colours
        # alike: grey, as bright as the horizon
        level = float(np.mean(horizon))
        grey = _smoothstep(15000.0, 2000.0, env.visibility_m) * 0.8
        haze = horizon * (1.0 - grey) + np.full(3, level) * grey
    return Lighting(
        sun_dir=sun_direction(az, el),
        sun_rgb=_rgb(sun),
        sky_rgb=_rgb(sky),
        ambient_rgb=_rgb(ambient),
        zenith_rgb=_rgb(zenith),
        horizon_rgb=_rgb(horizon),
        glow_rgb=_rgb(glow),
        haze_rgb=_rgb(haze),
        haze_per_m=haze_per_m,
        haze_max=haze_max,
        shadows=env.shadows and el > 0.5 and oc < 0.95,
        sun_disc=float(above * (1.0 - oc)),
        azimuth_deg=az,
        elevation_deg=el,
    )


def _with(base: Lighting, *, shadows: bool) -> Lighting:
    from dataclasses import replace  # noqa: PLC0415

    return replace(base, shadows=shadows)

"""Configuration of the SITL: frozen dataclasses, parsed once at start-up.

``config/sitl.yaml`` holds every setting with its default and unit; command-line
flags override single keys (see :mod:`sitl.cli`). Everything is validated here,
so an invalid value fails at start with the file, the key and what was expected.

Relative paths in the file (``params.file``, ``*.signing_key_file``) are resolved
against the directory of the config file.
"""

from __future__ import annotations

import copy
import enum
import itertools
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from sitl.core.estimator import NoiseModel
from sitl.core.params import ParamTable
from sitl.core.personality import ConfigDefaults, Personality, personality_named
from sitl.errors import SitlConfigError
from uav_common.config import ConfigError, deep_merge, from_mapping, load_yaml_mapping, set_dotted
from uav_common.validate import require, require_port

__all__ = [
    "ESTIMATOR_PRESETS",
    "AutopilotName",
    "BatteryConfig",
    "EstimatorConfig",
    "EstimatorMode",
    "EstimatorPreset",
    "FailsafeAction",
    "FailsafeConfig",
    "HomeConfig",
    "LinksConfig",
    "MavlinkConfig",
    "ParamsConfig",
    "PhysicsConfig",
    "SimLinkConfig",
    "SitlConfig",
    "StreamProfile",
    "TcpLinkConfig",
    "TimeConfig",
    "TimeMode",
    "TurbulenceLevel",
    "UdpLinkConfig",
    "WindConfig",
    "load_sitl_config",
    "params_for_config",
]


@dataclass(frozen=True)
class HomeConfig:
    """Home: the point on the ground under the vehicle at start, origin of LOCAL_NED."""

    lat_deg: float = 47.397742
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0
    yaw_deg: float = 0.0

    def __post_init__(self) -> None:
        require(-90.0 < self.lat_deg < 90.0, f"'lat_deg' must be in (-90, 90), got {self.lat_deg}")
        require(-180.0 <= self.lon_deg <= 180.0, f"'lon_deg' must be in [-180, 180], got {self.lon_deg}")
        require(-500.0 <= self.alt_amsl_m <= 9000.0, f"'alt_amsl_m' must be in [-500, 9000], got {self.alt_amsl_m}")
        require(math.isfinite(self.yaw_deg), "'yaw_deg' must be finite")


@dataclass(frozen=True)
class PhysicsConfig:
    """JSBSim model and the autopilot loop rates."""

    rate_hz: float = 250.0
    aircraft: str = "F450"
    aircraft_dir: Path | None = None
    outer_loop_divider: int = 5
    motor_max_voltage_v: float = 14.63
    thrust_curve_exponent: float = 1.68
    idle_thrust: float = 0.02

    def __post_init__(self) -> None:
        require(50.0 <= self.rate_hz <= 2000.0, f"'rate_hz' must be in [50, 2000] Hz, got {self.rate_hz}")
        require(1 <= self.outer_loop_divider <= 50, "'outer_loop_divider' must be in [1, 50]")
        require(self.motor_max_voltage_v > 0.0, "'motor_max_voltage_v' must be > 0")
        require(1.0 <= self.thrust_curve_exponent <= 3.0, "'thrust_curve_exponent' must be in [1, 3]")
        require(0.0 <= self.idle_thrust < 0.3, "'idle_thrust' must be in [0, 0.3)")
        require(bool(self.aircraft), "'aircraft' must not be empty")

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz


class TimeMode(enum.Enum):
    FREE = "free"
    LOCKSTEP = "lockstep"


@dataclass(frozen=True)
class TimeConfig:
    """Simulation clock: free-running at ``speed_factor`` or lockstep on SIM_STEP grants."""

    mode: TimeMode = TimeMode.FREE
    speed_factor: float | Literal["max"] = 1.0
    unix_epoch_s: float | None = None
    datalink_wall_floor_s: float = 3.0
    stream_wall_floor_s: float = 0.5
    max_lag_s: float = 0.25

    def __post_init__(self) -> None:
        if self.speed_factor != "max":
            require(
                isinstance(self.speed_factor, int | float) and 0.05 <= self.speed_factor <= 10000.0,
                f"'speed_factor' must be a number in [0.05, 10000] or 'max', got {self.speed_factor!r}",
            )
        require(0.0 <= self.datalink_wall_floor_s <= 60.0, "'datalink_wall_floor_s' must be in [0, 60] s")
        require(0.0 <= self.stream_wall_floor_s <= 60.0, "'stream_wall_floor_s' must be in [0, 60] s")
        require(0.0 < self.max_lag_s <= 10.0, "'max_lag_s' must be in (0, 10] s")
        if self.unix_epoch_s is not None:
            require(self.unix_epoch_s >= 0.0, "'unix_epoch_s' must be >= 0")

    @property
    def speed(self) -> float:
        """Speed factor as a number; ``inf`` for ``max``."""
        return math.inf if self.speed_factor == "max" else float(self.speed_factor)


_DEFAULT_OCV: tuple[tuple[float, float], ...] = (
    (0.00, 3.27),
    (0.05, 3.61),
    (0.10, 3.69),
    (0.15, 3.71),
    (0.20, 3.73),
    (0.30, 3.77),
    (0.40, 3.79),
    (0.50, 3.82),
    (0.60, 3.87),
    (0.70, 3.92),
    (0.80, 3.98),
    (0.90, 4.06),
    (1.00, 4.20),
)


@dataclass(frozen=True)
class BatteryConfig:
    """LiPo pack: capacity, cells, open-circuit voltage curve, internal resistance."""

    cells: int = 4
    capacity_mah: float = 3500.0
    internal_resistance_ohm: float = 0.03
    ocv_curve: tuple[tuple[float, float], ...] = _DEFAULT_OCV
    initial_soc: float = 1.0
    esc_efficiency: float = 0.90
    avionics_power_w: float = 4.0

    def __post_init__(self) -> None:
        require(1 <= self.cells <= 14, f"'cells' must be in [1, 14], got {self.cells}")
        require(100.0 <= self.capacity_mah <= 100000.0, "'capacity_mah' must be in [100, 100000]")
        require(0.0 <= self.internal_resistance_ohm <= 1.0, "'internal_resistance_ohm' must be in [0, 1]")
        require(0.0 <= self.initial_soc <= 1.0, "'initial_soc' must be in [0, 1]")
        require(0.3 <= self.esc_efficiency <= 1.0, "'esc_efficiency' must be in [0.3, 1]")
        require(0.0 <= self.avionics_power_w <= 500.0, "'avionics_power_w' must be in [0, 500]")
        socs = [p[0] for p in self.ocv_curve]
        volts = [p[1] for p in self.ocv_curve]
        require(len(self.ocv_curve) >= 2, "'ocv_curve' needs at least two [soc, volts] points")
        require(socs[0] == 0.0 and socs[-1] == 1.0, "'ocv_curve' must span soc 0.0 to 1.0")
        require(all(a < b for a, b in itertools.pairwise(socs)), "'ocv_curve' soc must increase strictly")
        require(all(a <= b for a, b in itertools.pairwise(volts)), "'ocv_curve' volts must not decrease")
        require(all(2.0 <= v <= 5.0 for v in volts), "'ocv_curve' cell volts must be in [2, 5]")


class FailsafeAction(enum.Enum):
    """What a failsafe does (values are the config spelling)."""

    DISABLED = "disabled"
    WARN = "warn"
    HOLD = "hold"
    RETURN = "return"
    LAND = "land"


@dataclass(frozen=True)
class FailsafeConfig:
    """Defaults of the failsafe parameters (PX4 names in comments)."""

    battery_action: Literal["warn", "return_land"] = "return_land"  # COM_LOW_BAT_ACT
    battery_low_remaining: float = 0.15  # BAT_LOW_THR -> return
    battery_critical_remaining: float = 0.07  # BAT_CRIT_THR -> land
    datalink_loss_action: FailsafeAction = FailsafeAction.DISABLED  # NAV_DLL_ACT
    datalink_loss_timeout_s: float = 10.0  # COM_DL_LOSS_T
    offboard_loss_action: FailsafeAction = FailsafeAction.HOLD  # COM_OBL_RC_ACT
    offboard_loss_timeout_s: float = 1.0  # COM_OF_LOSS_T
    geofence_action: FailsafeAction = FailsafeAction.RETURN  # GF_ACTION
    geofence_radius_m: float = 1000.0  # GF_MAX_HOR_DIST, 0 = off
    geofence_max_altitude_m: float = 120.0  # GF_MAX_VER_DIST, 0 = off

    def __post_init__(self) -> None:
        require(
            0.0 <= self.battery_critical_remaining < self.battery_low_remaining <= 0.5,
            ("need 0 <= battery_critical_remaining < battery_low_remaining <= 0.5"),
        )
        require(0.5 <= self.datalink_loss_timeout_s <= 300.0, "'datalink_loss_timeout_s' must be in [0.5, 300]")
        require(0.1 <= self.offboard_loss_timeout_s <= 60.0, "'offboard_loss_timeout_s' must be in [0.1, 60]")
        require(self.offboard_loss_action is not FailsafeAction.DISABLED, "'offboard_loss_action' cannot be disabled")
        require(self.offboard_loss_action is not FailsafeAction.WARN, "'offboard_loss_action' cannot be warn")
        require(0.0 <= self.geofence_radius_m <= 100000.0, "'geofence_radius_m' must be in [0, 100000]")
        require(0.0 <= self.geofence_max_altitude_m <= 10000.0, "'geofence_max_altitude_m' must be in [0, 10000]")


@dataclass(frozen=True)
class ParamsConfig:
    """Parameter table: the persisted file and default overrides by the personality's parameter names."""

    file: Path | None = None
    defaults: dict[str, float] = field(default_factory=dict)


class StreamProfile(enum.Enum):
    """PX4 mavlink stream sets: NORMAL for GCS links, ONBOARD for the API link."""

    NORMAL = "normal"
    ONBOARD = "onboard"


@dataclass(frozen=True)
class UdpLinkConfig:
    """A UDP MAVLink link: bind ``local_port``, send to ``remote`` and to peers that talk to us."""

    enabled: bool = True
    remote_host: str = "127.0.0.1"
    remote_port: int = 14550
    local_host: str = "0.0.0.0"
    local_port: int = 18570
    profile: StreamProfile = StreamProfile.NORMAL
    signing_key_file: Path | None = None

    def __post_init__(self) -> None:
        require_port("remote_port", self.remote_port)
        require_port("local_port", self.local_port, allow_zero=True)


@dataclass(frozen=True)
class TcpLinkConfig:
    """A TCP server; each accepted client is a MAVLink peer."""

    enabled: bool = True
    host: str = "0.0.0.0"
    port: int = 5760
    profile: StreamProfile = StreamProfile.ONBOARD
    signing_key_file: Path | None = None
    max_clients: int = 8

    def __post_init__(self) -> None:
        require_port("port", self.port, allow_zero=True)
        require(1 <= self.max_clients <= 64, "'max_clients' must be in [1, 64]")


def _api_link() -> UdpLinkConfig:
    return UdpLinkConfig(remote_port=14540, local_port=14580, profile=StreamProfile.ONBOARD)


@dataclass(frozen=True)
class LinksConfig:
    """The three vehicle links, like PX4 SITL instance 0."""

    gcs: UdpLinkConfig = field(default_factory=UdpLinkConfig)
    api: UdpLinkConfig = field(default_factory=_api_link)
    tcp: TcpLinkConfig = field(default_factory=TcpLinkConfig)


@dataclass(frozen=True)
class SimLinkConfig:
    """The simulation link to the sensor bridge / lockstep master (docs/architecture.md)."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: int = 4560
    rate_hz: float = 50.0
    peer_timeout_s: float = 5.0
    max_steps_per_grant: int = 250000

    def __post_init__(self) -> None:
        require_port("port", self.port, allow_zero=True)
        require(1.0 <= self.rate_hz <= 1000.0, "'rate_hz' must be in [1, 1000]")
        require(0.5 <= self.peer_timeout_s <= 600.0, "'peer_timeout_s' must be in [0.5, 600]")
        require(1 <= self.max_steps_per_grant <= 10_000_000, "'max_steps_per_grant' must be in [1, 1e7]")


class EstimatorMode(enum.Enum):
    TRUTH = "truth"
    NOISY = "noisy"


class EstimatorPreset(enum.Enum):
    """A named set of the noisy estimator's numbers (:data:`ESTIMATOR_PRESETS`)."""

    RTK = "rtk"
    GPS = "gps"
    POOR_GPS = "poor_gps"


#: The noisy estimator's presets: ``estimator.preset`` fills in every key it does not set explicitly.
#: Per-axis standard deviations; a circular Gaussian's CEP (50 %) is 1.18 of its per-axis sigma. Where the
#: numbers come from is in docs/sitl.md "Estimator presets".
ESTIMATOR_PRESETS: dict[EstimatorPreset, dict[str, float]] = {
    # u-blox ZED-F9P with RTK fixed (datasheet: 0.01 m + 1 ppm CEP; baseline within ~10 km -> <= 2 cm CEP);
    # the heading still comes from a well-calibrated compass.
    EstimatorPreset.RTK: {
        "horizontal_noise_m": 0.02,
        "vertical_noise_m": 0.03,
        "velocity_noise_mps": 0.02,
        "attitude_noise_rad": 0.003,
        "noise_correlation_s": 10.0,
        "horizontal_bias_m": 0.02,
        "vertical_bias_m": 0.03,
        "heading_bias_deg": 1.5,
        "heading_noise_deg": 0.5,
        "heading_correlation_s": 60.0,
        "gps_dropouts_per_hour": 0.0,
        "gps_dropout_duration_s": 5.0,
        "dropout_drift_mps": 0.3,
    },
    # single-band u-blox M8N / M9N under open sky (datasheets: 2.5 m / 1.5 m CEP): 2.0 m CEP, half of it a
    # per-run bias and half a wander correlated over 30 s (EKF2 smooths the receiver's jitter, not its slow
    # ionosphere / multipath errors); a compass heading off by ~3 degrees (declination, calibration)
    EstimatorPreset.GPS: {
        "horizontal_noise_m": 1.2,
        "vertical_noise_m": 1.5,
        "velocity_noise_mps": 0.1,
        "attitude_noise_rad": 0.005,
        "noise_correlation_s": 30.0,
        "horizontal_bias_m": 1.2,
        "vertical_bias_m": 1.5,
        "heading_bias_deg": 3.0,
        "heading_noise_deg": 1.0,
        "heading_correlation_s": 60.0,
        "gps_dropouts_per_hour": 2.0,
        "gps_dropout_duration_s": 3.0,
        "dropout_drift_mps": 0.3,
    },
    # single-band GNSS near trees and buildings (multipath, fewer satellites): 4.2 m CEP, a compass near
    # metal or power lines (6 degrees), a fix lost every ~5 minutes for 8 s
    EstimatorPreset.POOR_GPS: {
        "horizontal_noise_m": 2.5,
        "vertical_noise_m": 2.5,
        "velocity_noise_mps": 0.3,
        "attitude_noise_rad": 0.01,
        "noise_correlation_s": 20.0,
        "horizontal_bias_m": 2.5,
        "vertical_bias_m": 2.0,
        "heading_bias_deg": 6.0,
        "heading_noise_deg": 2.0,
        "heading_correlation_s": 30.0,
        "gps_dropouts_per_hour": 12.0,
        "gps_dropout_duration_s": 8.0,
        "dropout_drift_mps": 0.5,
    },
}


@dataclass(frozen=True)
class EstimatorConfig:
    """What the autopilot believes: the truth, or truth + seeded noise, bias, heading error and GPS dropouts.

    ``preset`` names a set of the noise numbers (:data:`ESTIMATOR_PRESETS`); :func:`load_sitl_config` fills
    them in for every key the configuration does not set itself (:meth:`from_preset` does it in code).
    """

    mode: EstimatorMode = EstimatorMode.TRUTH
    seed: int = 0
    preset: EstimatorPreset | None = None
    horizontal_noise_m: float = 0.05
    vertical_noise_m: float = 0.08
    velocity_noise_mps: float = 0.03
    attitude_noise_rad: float = 0.002
    noise_correlation_s: float = 1.0
    horizontal_bias_m: float = 0.2
    vertical_bias_m: float = 0.3
    heading_bias_deg: float = 0.0
    heading_noise_deg: float = 0.0
    heading_correlation_s: float = 60.0
    gps_dropouts_per_hour: float = 0.0
    gps_dropout_duration_s: float = 5.0
    dropout_drift_mps: float = 0.3

    def __post_init__(self) -> None:
        for name in (
            "horizontal_noise_m",
            "vertical_noise_m",
            "velocity_noise_mps",
            "attitude_noise_rad",
            "horizontal_bias_m",
            "vertical_bias_m",
            "gps_dropouts_per_hour",
            "dropout_drift_mps",
        ):
            value = getattr(self, name)
            require(0.0 <= value <= 1000.0, f"'{name}' must be in [0, 1000], got {value}")
        for name in ("heading_bias_deg", "heading_noise_deg"):
            value = getattr(self, name)
            require(0.0 <= value <= 90.0, f"'{name}' must be in [0, 90] degrees, got {value}")
        require(0.01 <= self.noise_correlation_s <= 1000.0, "'noise_correlation_s' must be in [0.01, 1000]")
        require(
            0.01 <= self.heading_correlation_s <= 3600.0,
            f"'heading_correlation_s' must be in [0.01, 3600], got {self.heading_correlation_s}",
        )
        require(0.1 <= self.gps_dropout_duration_s <= 3600.0, "'gps_dropout_duration_s' must be in [0.1, 3600]")
        require(0 <= self.seed < 2**63, "'seed' must be a non-negative integer")
        require(
            self.preset is None or self.mode is EstimatorMode.NOISY,
            f"'preset' {self.preset.value if self.preset else ''!r} needs 'mode: noisy' (mode truth reports the "
            "truth and would ignore it); set mode: noisy or remove the preset (preset: null)",
        )

    def noise_model(self) -> NoiseModel | None:
        """The estimator core's noise model (None: the truth)."""
        if self.mode is EstimatorMode.TRUTH:
            return None
        return NoiseModel(
            self.horizontal_noise_m,
            self.vertical_noise_m,
            self.velocity_noise_mps,
            self.attitude_noise_rad,
            self.noise_correlation_s,
            self.horizontal_bias_m,
            self.vertical_bias_m,
            self.gps_dropouts_per_hour,
            self.gps_dropout_duration_s,
            self.dropout_drift_mps,
            math.radians(self.heading_bias_deg),
            math.radians(self.heading_noise_deg),
            self.heading_correlation_s,
        )

    @classmethod
    def from_preset(cls, preset: EstimatorPreset | str, **overrides: Any) -> EstimatorConfig:
        """A noisy estimator with ``preset``'s numbers; ``overrides`` win over them."""
        p = EstimatorPreset(preset)
        values: dict[str, Any] = {"mode": EstimatorMode.NOISY, **ESTIMATOR_PRESETS[p], **overrides}
        return cls(preset=p, **values)


def _apply_estimator_preset(data: dict[str, Any], source: str) -> None:
    """Fill ``estimator.preset``'s numbers into ``data`` wherever it does not set a key itself."""
    est = data.get("estimator")
    if not isinstance(est, dict) or est.get("preset") is None:
        return
    name = est["preset"]
    choices = ", ".join(p.value for p in EstimatorPreset)
    try:
        preset = EstimatorPreset(name)
    except ValueError:
        msg = f"{source}: 'estimator.preset': unknown preset {name!r}; choose one of {choices} (docs/sitl.md)"
        raise SitlConfigError(msg) from None
    for key, value in ESTIMATOR_PRESETS[preset].items():
        est.setdefault(key, value)


@dataclass(frozen=True)
class MavlinkConfig:
    """Our MAVLink identity and the wall-clock heartbeat used while simulation time is paused."""

    system_id: int = 1
    component_id: int = 1
    paused_heartbeat_period_s: float = 1.0
    stats_period_s: float = 10.0

    def __post_init__(self) -> None:
        require(1 <= self.system_id <= 254, "'system_id' must be in [1, 254]")
        require(1 <= self.component_id <= 254, "'component_id' must be in [1, 254]")
        require(0.1 <= self.paused_heartbeat_period_s <= 10.0, "'paused_heartbeat_period_s' must be in [0.1, 10]")
        require(0.0 <= self.stats_period_s <= 3600.0, "'stats_period_s' must be in [0, 3600] (0 = off)")


class TurbulenceLevel(enum.Enum):
    """Dryden turbulence level (MIL-F-8785C's wind at 20 ft: 15, 30, 45 kt)."""

    NONE = "none"
    LIGHT = "light"
    MODERATE = "moderate"
    SEVERE = "severe"


@dataclass(frozen=True)
class WindConfig:
    """The air the vehicle flies in: mean wind by height (power law) and seeded Dryden turbulence."""

    speed_mps: float = 0.0
    from_deg: float = 0.0
    reference_height_m: float = 10.0
    shear_exponent: float = 0.0
    turbulence: TurbulenceLevel = TurbulenceLevel.NONE
    seed: int = 0

    def __post_init__(self) -> None:
        require(0.0 <= self.speed_mps <= 40.0, f"'speed_mps' must be in [0, 40], got {self.speed_mps}")
        require(0.0 <= self.from_deg <= 360.0, f"'from_deg' must be in [0, 360], got {self.from_deg}")
        require(
            1.0 <= self.reference_height_m <= 500.0,
            f"'reference_height_m' must be in [1, 500], got {self.reference_height_m}",
        )
        require(0.0 <= self.shear_exponent <= 1.0, f"'shear_exponent' must be in [0, 1], got {self.shear_exponent}")
        require(0 <= self.seed < 2**63, "'seed' must be a non-negative integer")

    @property
    def enabled(self) -> bool:
        return self.speed_mps > 0.0 or self.turbulence is not TurbulenceLevel.NONE


class AutopilotName(enum.Enum):
    """Which autopilot the SITL is (``--autopilot``): its heartbeat, modes, parameters and conventions."""

    PX4 = "px4"
    ARDUPILOT = "ardupilot"


@dataclass(frozen=True)
class SitlConfig:
    """Everything ``uav-sitl`` needs; one instance per process."""

    autopilot: AutopilotName = AutopilotName.PX4
    home: HomeConfig = field(default_factory=HomeConfig)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    time: TimeConfig = field(default_factory=TimeConfig)
    battery: BatteryConfig = field(default_factory=BatteryConfig)
    failsafe: FailsafeConfig = field(default_factory=FailsafeConfig)
    params: ParamsConfig = field(default_factory=ParamsConfig)
    links: LinksConfig = field(default_factory=LinksConfig)
    sim_link: SimLinkConfig = field(default_factory=SimLinkConfig)
    estimator: EstimatorConfig = field(default_factory=EstimatorConfig)
    wind: WindConfig = field(default_factory=WindConfig)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)

    @property
    def personality(self) -> Personality:
        return personality_named(self.autopilot.value)


def params_for_config(cfg: SitlConfig) -> ParamTable:
    """The personality's parameter table with defaults from the config (failsafe section, ``params.defaults``).

    Raises:
        ValueError: a default names a parameter this personality does not have (the message says which
            personality has it) or is out of range.
    """
    fs = cfg.failsafe
    personality = cfg.personality
    defaults = personality.config_defaults(
        ConfigDefaults(
            battery_return_land=fs.battery_action == "return_land",
            battery_low_remaining=fs.battery_low_remaining,
            battery_critical_remaining=fs.battery_critical_remaining,
            battery_capacity_mah=cfg.battery.capacity_mah,
            battery_cells=cfg.battery.cells,
            datalink_action=fs.datalink_loss_action.value,
            datalink_timeout_s=fs.datalink_loss_timeout_s,
            offboard_action=fs.offboard_loss_action.value,
            offboard_timeout_s=fs.offboard_loss_timeout_s,
            geofence_action=fs.geofence_action.value,
            geofence_radius_m=fs.geofence_radius_m,
            geofence_max_altitude_m=fs.geofence_max_altitude_m,
            system_id=cfg.mavlink.system_id,
        )
    )
    defaults.update(cfg.params.defaults)
    return personality.param_table(defaults)


_PATH_KEYS = (
    ("params", "file"),
    ("links", "gcs", "signing_key_file"),
    ("links", "api", "signing_key_file"),
    ("links", "tcp", "signing_key_file"),
    ("physics", "aircraft_dir"),
)


def _resolve_paths(data: dict[str, Any], base: Path) -> None:
    for keys in _PATH_KEYS:
        node: Any = data
        for key in keys[:-1]:
            node = node.get(key) if isinstance(node, Mapping) else None
        if isinstance(node, dict):
            value = node.get(keys[-1])
            if isinstance(value, str) and value:
                path = Path(value).expanduser()
                node[keys[-1]] = str(path if path.is_absolute() else (base / path).resolve())


def load_sitl_config(
    path: Path | None,
    overrides: Mapping[str, Any] | None = None,
) -> SitlConfig:
    """Load ``path`` (or the built-in defaults when ``None``) and apply dotted overrides.

    Args:
        path: a YAML file; relative paths inside it resolve against its directory.
        overrides: ``{"links.gcs.remote_port": 14551, ...}`` from the command line;
            relative paths in them resolve against the current directory.

    Raises:
        SitlConfigError: missing file, bad YAML, unknown key, wrong type or an
            invalid value; the message names the source and the key.
    """
    try:
        data: dict[str, Any] = load_yaml_mapping(path) if path is not None else {}
    except ConfigError as err:
        raise SitlConfigError(str(err)) from err
    data = copy.deepcopy(data)
    if path is not None:
        _resolve_paths(data, path.resolve().parent)
    source = str(path) if path is not None else "built-in defaults"
    if overrides:
        extra: dict[str, Any] = {}
        try:
            for key, value in overrides.items():
                set_dotted(extra, key, value)
        except ConfigError as err:
            raise SitlConfigError(str(err)) from err
        _resolve_paths(extra, Path.cwd())
        data = deep_merge(data, extra)
        source += " + command-line overrides (" + ", ".join(sorted(overrides)) + ")"
    _apply_estimator_preset(data, source)
    try:
        cfg = from_mapping(SitlConfig, data, source=source)
    except ConfigError as err:
        raise SitlConfigError(str(err)) from err
    try:
        params_for_config(cfg)
    except ValueError as err:
        msg = f"{source}: params.defaults / failsafe ({cfg.autopilot.value} personality): {err}"
        raise SitlConfigError(msg) from err
    return cfg

"""Schema of the `env` config group: the embedded LaneDrive simulator, or TORCS (Hydra structured config).

The simulator named by ``id`` takes these same fields as keyword arguments of ``gymnasium.make(id, ...)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

SIMULATORS = ("LaneDrive-v0", "TorcsDrive-v0")  # the gymnasium ids an actor and the evaluator can drive
# |alpha| from which a step counts as off the centre (the target is a mean of 0.1); alpha > 0
# is left of the centre and positive steering (left) moves alpha up
OFF_CENTRE = 0.3


@dataclass
class DamageConfig:
    """Lane-marking damage for robustness tests (all zero: pristine markings)."""

    gap_fraction: float = 0.0
    """Fraction of each lane marking removed in random 1-6 m gaps."""
    fade_fraction: float = 0.0
    """Fraction of each lane marking faded to 15-50% contrast in 3-15 m stretches."""
    distractors_per_100m: float = 0.0
    """Random white strokes painted on the road surface per 100 m of road."""


@dataclass
class VehicleConfig:
    """Kinematic bicycle with a steering-rate limit, a speed lag and a lateral-grip limit."""

    wheelbase: float = 2.6
    """Distance between axles, m."""
    max_steer: float = 0.5
    """Steering angle at action +-1, rad."""
    steer_rate: float = 1.5
    """Fastest steering change, rad/s."""
    v_max: float = 20.0
    """Speed at target-speed action +1, m/s; action -1 asks for half of it."""
    speed_lag: float = 1.0
    """Time constant of the first-order lag from target speed to speed, s."""
    max_lateral_accel: float = 8.0
    """Grip limit; above it the car understeers (path curvature capped at a/v^2), m/s^2."""
    dt: float = 0.1
    """Control period, s (10 Hz, as the paper)."""


NOISE_FREE = {"lighting": False, "gust_rate": 0.0}  # what every evaluation drive sets: no training randomisation


@dataclass
class EnvConfig:
    """LaneDrive-v0: a lane-keeping car with a front camera on closed roads."""

    id: str = "LaneDrive-v0"
    """Gymnasium id of the simulator: 'LaneDrive-v0' (embedded) or 'TorcsDrive-v0' (TORCS, after `make torcs`)."""
    track: str = "train"
    """Road set sampled at reset: 'train', 'test', 'all', 'procedural', or one library name."""
    direction: str = "random"
    """Driving direction: 'ccw', 'cw' or 'random' (per episode)."""
    lane_width: float = 6.0
    """Distance between the two lane markings, m (alpha = +-1 on them)."""
    max_steps: int = 1200
    """Truncation horizon in steps (120 s at 10 Hz, as the paper)."""
    random_start: bool = True
    """Start at a random place on the lap with a small random offset; False starts at s=0, centred."""
    lighting: bool = True
    """Randomise brightness and contrast per episode."""
    gust_rate: float = 0.0
    """Training only (LaneDrive): chance per car and step of a heading kick of up to `gust_yaw`, so
    that recoveries from off the centre stay in the replay; evaluation drives never gust. 0: none."""
    gust_yaw: float = 0.15
    """The kick's largest size, rad (uniform in +-gust_yaw)."""
    camera_height: float = 1.5
    """Height of the level front camera, m: the top image row sees 40x as far ahead."""
    damage: DamageConfig = field(default_factory=DamageConfig)
    """Lane-marking damage and distractors."""
    vehicle: VehicleConfig = field(default_factory=VehicleConfig)
    """Vehicle dynamics."""

    @classmethod
    def from_kwargs(cls, **kwargs) -> "EnvConfig":
        """Build from plain keyword arguments (nested groups as dicts), refusing unknown names."""
        known = {f.name for f in fields(cls)}
        unknown = set(kwargs) - known
        if unknown:
            raise TypeError(f"unknown LaneDrive option(s) {sorted(unknown)}; known: {sorted(known)}")
        damage = kwargs.pop("damage", None) or {}
        vehicle = kwargs.pop("vehicle", None) or {}
        cfg = cls(
            damage=damage if isinstance(damage, DamageConfig) else DamageConfig(**dict(damage)),
            vehicle=vehicle if isinstance(vehicle, VehicleConfig) else VehicleConfig(**dict(vehicle)),
            **kwargs,
        )
        cfg.validate()
        return cfg

    def validate(self) -> None:
        """Refuse a bad config with a message that names the field."""
        if self.id not in SIMULATORS:
            raise ValueError(f"env.id must be one of {SIMULATORS}, got {self.id!r}")
        if self.id == "TorcsDrive-v0" and self.track == "procedural":
            raise ValueError("env.track: TorcsDrive-v0 drives torcs-data roads ('train', 'test', 'all' or a road name)")
        if self.direction not in ("ccw", "cw", "random"):
            raise ValueError(f"env.direction must be 'ccw', 'cw' or 'random', got {self.direction!r}")
        if not 2.0 <= self.lane_width <= 12.0:
            raise ValueError(f"env.lane_width must be in [2, 12] m, got {self.lane_width}")
        if not 0.5 <= self.camera_height <= 3.0:  # the road maps reach 125 m: 40 x 3 m, plus 1
            raise ValueError(f"env.camera_height must be in [0.5, 3] m, got {self.camera_height}")
        if self.max_steps < 1:
            raise ValueError(f"env.max_steps must be >= 1, got {self.max_steps}")
        if not 0.0 <= self.gust_rate <= 1.0:
            raise ValueError(f"env.gust_rate must be in [0, 1], got {self.gust_rate}")
        if not 0.0 <= self.gust_yaw <= 0.5:
            raise ValueError(f"env.gust_yaw must be in [0, 0.5] rad, got {self.gust_yaw}")
        if self.gust_rate and self.id != "LaneDrive-v0":
            raise ValueError("env.gust_rate: gusts are LaneDrive's only (TORCS drives without)")
        for name in ("gap_fraction", "fade_fraction"):
            if not 0.0 <= getattr(self.damage, name) <= 1.0:
                raise ValueError(f"env.damage.{name} must be in [0, 1], got {getattr(self.damage, name)}")
        if self.damage.distractors_per_100m < 0:
            raise ValueError("env.damage.distractors_per_100m must be >= 0")

"""Section dataclasses as Hydra structured configs (Hydra checks keys and types), and the value
range checks their `validate()` runs once per run; errors are one line naming `section.key`."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar, TypeVar

from hydra.core.config_store import ConfigStore
from omegaconf import OmegaConf
from omegaconf.errors import OmegaConfBaseException

from relaygs.data.options import INT64_MAX
from relaygs.errors import InputError, one_line
from relaygs.model import (
    BACKGROUND_DENSIFY,
    CORE_PARAMS,
    FOREGROUND_DENSIFY,
    DensifySettings,
    LRSchedule,
    SetLearningRates,
)

T = TypeVar("T")
S = TypeVar("S", bound="Section")


def parse_section(cls: type[T], data: Mapping[str, Any] | None, section: str) -> T:
    """Dataclass `cls` from `data` over its defaults; OmegaConf refuses bad keys and types."""
    try:
        parsed = OmegaConf.to_object(OmegaConf.merge(OmegaConf.structured(cls), data or {}))
    except OmegaConfBaseException as error:
        where = ".".join(filter(None, (section, str(getattr(error, "full_key", "") or ""))))
        raise InputError(f"{where}: {one_line(error)}") from error
    for name, value in dataclasses.asdict(parsed).items():
        # torch and numpy take no int beyond int64 (a traceback deep in a stage otherwise)
        big = isinstance(value, int) and abs(value) > INT64_MAX
        require(not big, f"{section}.{name}", value, f"an int <= {INT64_MAX}")
    return parsed


class Section:
    """Base of the section dataclasses; `section` is the config key `from_config` parses."""

    section: ClassVar[str]

    @classmethod
    def from_config(cls: type[S], data: Mapping[str, Any] | None) -> S:
        """Parse `cfg[section]` (missing keys keep defaults)."""
        return parse_section(cls, data, cls.section)


def register_schemas(sections: Mapping[str, type]) -> None:
    """Store each section's dataclass as Hydra's `<section>/schema`, checked on compose."""
    store = ConfigStore.instance()
    for name, cls in sections.items():
        store.store(group=name, name="schema", node=cls)


def require(condition: bool, where: str, value: Any, expected: str) -> None:
    """Raise a one-line InputError `where: expected <expected>, got <value>` unless `condition`."""
    if not condition:
        raise InputError(f"{where}: expected {expected}, got {value!r}")


def require_steps(where: str, value: int) -> None:
    require(value >= 0, where, value, "a step count >= 0")


def json_ready(value: Any) -> Any:
    """`value` with tuples turned into lists and dataclasses into dicts (for JSON metadata)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: json_ready(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {str(key): json_ready(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [json_ready(item) for item in value]
    return value


def learning_rates(config: Mapping[str, Any], steps: int, where: str) -> SetLearningRates:
    """Per-parameter schedules from a config mapping, decaying over `steps` unless told."""
    checked: dict[str, Any] = {  # an unknown name is left for from_config to name
        name: _rate_config(value, f"{where}.{name}") if name in CORE_PARAMS else value
        for name, value in config.items()
        if name != "extras"
    }
    extras = config.get("extras") or {}
    require(isinstance(extras, Mapping), f"{where}.extras", extras, "a mapping of rates")
    checked["extras"] = {
        name: _rate_config(value, f"{where}.extras.{name}") for name, value in extras.items()
    }
    rates = SetLearningRates.from_config(checked, where)
    core = {
        name: _resolved(rates.for_param(name), steps, f"{where}.{name}") for name in CORE_PARAMS
    }
    extras = {
        name: _resolved(value, steps, f"{where}.extras.{name}")
        for name, value in rates.extras.items()
    }
    return SetLearningRates(**core, extras=extras)


class PerSetSections(Section):
    """Base of stage settings with `steps` and per set ("bg", "fg") `lr_<set>`, `densify_<set>`."""

    steps: int

    def set_rates(self, name: str) -> SetLearningRates:
        """Learning-rate schedules of set `name` over the stage's steps."""
        key = f"lr_{name}"
        return learning_rates(getattr(self, key), self.steps, f"{self.section}.{key}")

    def set_densify(self, name: str) -> DensifySettings:
        """Density control of set `name`: the paper's fg or bg settings with the overrides."""
        base = FOREGROUND_DENSIFY if name == "fg" else BACKGROUND_DENSIFY
        key = f"densify_{name}"
        return densify_settings(getattr(self, key), base, f"{self.section}.{key}", self.steps)


def schedule(value: float | Mapping[str, Any], steps: int, where: str) -> LRSchedule:
    """One learning rate (number or {init, final, ...}); decays over `steps` unless told."""
    return _resolved(LRSchedule.from_config(_rate_config(value, where)), steps, where)


def _rate_config(value: Any, where: str) -> float | dict[str, Any]:
    """One rate, type-checked (LRSchedule.from_config trusts its input): a number, or a mapping
    of LRSchedule's fields with `init`; a bool, string or null is refused."""
    if isinstance(value, Mapping) and "init" in value:
        return dataclasses.asdict(parse_section(LRSchedule, value, where))
    number = isinstance(value, int | float) and not isinstance(value, bool)
    require(number, where, value, "a number or a mapping with an 'init' rate")
    return float(value)


def _resolved(parsed: LRSchedule, steps: int, where: str) -> LRSchedule:
    _check_schedule(parsed, where)
    if parsed.final is not None and parsed.max_steps == 0:
        return dataclasses.replace(parsed, max_steps=max(steps, 1))
    return parsed


def _check_schedule(schedule: LRSchedule, where: str) -> None:
    name = where if schedule.final is None else f"{where}.init"
    require(0.0 <= schedule.init < math.inf, name, schedule.init, "a finite learning rate >= 0")
    if schedule.final is not None:
        final = schedule.final
        require(0.0 < final < math.inf, f"{where}.final", final, "a finite final rate > 0")
        require(schedule.init > 0.0, f"{where}.init", schedule.init, "an initial rate > 0")
    require(schedule.max_steps >= 0, f"{where}.max_steps", schedule.max_steps, "an int >= 0")
    require(schedule.delay_steps >= 0, f"{where}.delay_steps", schedule.delay_steps, "an int >= 0")
    mult = schedule.delay_mult
    # an infinite or NaN multiplier gives a NaN rate, which turns the first step's parameters NaN
    require(0.0 <= mult < math.inf, f"{where}.delay_mult", mult, "a finite number >= 0")


def densify_settings(
    config: Mapping[str, Any], base: DensifySettings, where: str, steps: int
) -> DensifySettings:
    """`base` with `config`'s keys, checked and ended by the stage's last step (a split or reset
    there would be saved with no step left to optimise it)."""
    settings = parse_section(DensifySettings, {**dataclasses.asdict(base), **config}, where)
    _check_densify(settings, where)
    return dataclasses.replace(settings, densify_until=min(settings.densify_until, steps))


def _check_densify(settings: DensifySettings, where: str) -> None:
    """The ranges of density-control settings (errors name `<where>.<key>`)."""
    # infinity would pass as "never split", but cannot be written to the artifact's JSON meta
    for name in ("grad_threshold", "percent_dense", "max_world_size"):
        value = getattr(settings, name)
        require(0.0 < value < math.inf, f"{where}.{name}", value, "a finite number > 0")
    # an infinite divisor gives split children a log-scale of -inf: the training diverges
    divisor = settings.split_scale_divisor
    key = f"{where}.split_scale_divisor"
    require(0.0 < divisor < math.inf, key, divisor, "a finite number > 0")
    # a radius <= 0 prunes every Gaussian ever seen; NaN would silently never prune
    radius = settings.max_screen_radius
    key = f"{where}.max_screen_radius"
    require(radius is None or 0.0 < radius < math.inf, key, radius, "None or a finite number > 0")
    for name in ("densify_from", "densify_until", "opacity_reset_every"):
        require_steps(f"{where}.{name}", getattr(settings, name))
    require(settings.densify_every >= 1, f"{where}.densify_every", settings.densify_every, ">= 1")
    require(settings.split_count >= 2, f"{where}.split_count", settings.split_count, ">= 2")
    # a reset to opacity 0 is a logit of -inf: every Gaussian goes dark for good, then is pruned
    reset = settings.reset_opacity
    require(0.0 < reset < 1.0, f"{where}.reset_opacity", reset, "an opacity in (0, 1)")
    prune = settings.prune_opacity
    require(0.0 <= prune < 1.0, f"{where}.prune_opacity", prune, "an opacity in [0, 1)")
    cap = settings.max_gaussians
    require(cap is None or cap >= 1, f"{where}.max_gaussians", cap, "None or an int >= 1")

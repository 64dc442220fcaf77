"""What Hydra cannot check of a `python -m relaygs.run` command before its first job starts:
every job the command would launch is composed and planned, its scene overrides checked and
the run (sweep) folder tried, so a sweep does not find a bad value only when its job comes up."""

from __future__ import annotations

import itertools
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import yaml
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from relaygs.errors import InputError, one_line
from relaygs.paths import require_creatable_folder

MULTIRUN_FLAGS = frozenset({"-m", "--multirun"})
LAUNCH_FLAGS = MULTIRUN_FLAGS | {"-r", "--run"}
"""Flags that run jobs (the others print); Hydra reads them only before the overrides."""
MODE_FLAGS = {
    **{"-r": "--run", "-m": "--multirun", "-c": "--cfg", "-i": "--info"},
    **{"-sc": "--shell-completion", "--run": "--run", "--multirun": "--multirun"},
    **{"--cfg": "--cfg", "--info": "--info", "--shell-completion": "--shell-completion"},
}
"""Hydra's flags that choose what the command does: it takes one (a second is a traceback)."""
MULTIRUN_RECORD = "multirun.yaml"
"""What Hydra writes into a sweep folder: the sweep's config, its overrides included."""
REMOTE_LAUNCHERS = {
    "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher": ("sbatch", "srun")
}
"""Launchers whose jobs run elsewhere (their device is checked there), with the commands they
submit through, which must be on this machine's PATH."""
SYNTHETIC_ONLY = (
    "scene",
    "scene.preset",
    "scene.frames",
    "scene.width",
    "scene.height",
    "scene.seed",
)
"""Overrides that only a synthetic scene takes: a capture (`scene.path`) has its own."""

JobValidator = Callable[[DictConfig, bool], None]
"""Raises InputError for a bad composed job; the flag says whether the job runs here."""


def check_command_line(argv: Sequence[str], conf_dir: Path, validate: JobValidator) -> None:
    """Compose every job a running command would launch and `validate` it, then check its
    scene overrides, submit commands and run folder (commands that only print are Hydra's)."""
    modes = {MODE_FLAGS[arg.split("=")[0]] for arg in argv if arg.split("=")[0] in MODE_FLAGS}
    if len(modes) > 1:
        raise InputError(f"{' and '.join(sorted(modes))} cannot be combined: Hydra takes one")
    if any(arg.startswith("-") and arg not in LAUNCH_FLAGS for arg in argv):
        # parsed here: Hydra's --info sets up its logging before it parses them
        parse_overrides([arg for arg in argv if "=" in arg and not arg.startswith("-")])
        return
    args = [arg for arg in argv if arg not in LAUNCH_FLAGS]
    overrides = parse_overrides(args)
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3", job_name="run"):
        plain = [o.input_line for o in overrides if not o.is_sweep_override()]
        hydra_cfg = compose("config", overrides=plain, return_hydra_config=True).hydra
        # --run does not override a config's `hydra.mode: MULTIRUN`; --multirun does
        multirun = bool(MULTIRUN_FLAGS & set(argv)) or hydra_cfg.mode == RunMode.MULTIRUN
        launcher = hydra_cfg.launcher.get("_target_")
        runs_here = not multirun or launcher not in REMOTE_LAUNCHERS
        if not runs_here:
            _check_submit_commands(launcher)
        jobs = planned_jobs(args, hydra_cfg, multirun)
        swept = swept_keys(jobs)
        for job in jobs:
            try:
                check_capture_overrides(job)
                validate(compose("config", overrides=job), runs_here)
            except InputError as error:
                named = [arg for arg in job if arg.partition("=")[0] in swept] or job
                where = f"job {' '.join(named)}: " if job != args else ""
                raise InputError(f"{where}{error}") from error
        check_output_folder(hydra_cfg, multirun)  # after the jobs' own paths, often its parents


def library_error_line(error: BaseException) -> str:
    """Hydra's or OmegaConf's message in one line, with its cause's (Hydra's "Error merging
    override relay.k=x" says why only in its cause)."""
    cause = error.__cause__
    return one_line(error) + (f": {one_line(cause)}" if cause and str(cause) else "")


def swept_keys(jobs: Sequence[Sequence[str]]) -> set[str]:
    """The override keys whose value differs between `jobs`: what names a job among them."""
    values: dict[str, set[str]] = {}
    for job in jobs:
        for arg in job:
            key, _, value = arg.partition("=")
            values.setdefault(key, set()).add(value)
    return {key for key, seen in values.items() if len(seen) > 1}


def check_capture_overrides(job: Sequence[str]) -> None:
    """A job that reads a capture (`scene.path=DIR`) must not also set what only a synthetic
    preset has: the capture would ignore it, though the result would record it."""
    settings = {o.key_or_group: o for o in parse_overrides(job)}  # the last one of a key counts
    path = settings.get("scene.path")
    if path is None or path.is_delete() or path.value() in (None, ""):
        return
    ignored = [o for key, o in settings.items() if key in SYNTHETIC_ONLY and not o.is_delete()]
    if ignored:
        raise InputError(
            f"{ignored[0].input_line.lstrip('+')} sets a synthetic scene, but scene.path reads "
            "a capture, whose frames, size and cameras are its own: drop one of the two"
        )


def check_output_folder(hydra_cfg: DictConfig, multirun: bool) -> None:
    """`hydra.run.dir` (`hydra.sweep.dir` for a multirun) must be a writable or creatable folder."""
    key = "sweep" if multirun else "run"
    text = str(hydra_cfg[key].dir)
    if not text.strip():
        # Path("") is the folder the command started in, which would get the run's files
        raise InputError(f"hydra.{key}.dir: expected a path (a non-empty string), got {text!r}")
    require_creatable_folder(Path(text).expanduser().absolute(), f"hydra.{key}.dir")


def planned_jobs(args: list[str], hydra_cfg: DictConfig, multirun: bool) -> list[list[str]]:
    """The override lists of the jobs this command line would run (for a sweeper other than
    the basic one, whose jobs only it knows, its plain overrides)."""
    if not multirun:
        return [args]
    overrides = parse_overrides(args)
    if not _is_basic_sweeper(hydra_cfg):
        return [[o.input_line for o in overrides if not o.is_sweep_override()]]
    params = [f"{key}={value}" for key, value in (hydra_cfg.sweeper.get("params") or {}).items()]
    return sweep_jobs(parse_overrides([*params, *args]))


def _is_basic_sweeper(hydra_cfg: DictConfig) -> bool:
    """Whether the sweep runs with Hydra's basic sweeper, whose jobs `sweep_jobs` lists."""
    return str(hydra_cfg.sweeper.get("_target_", "")).endswith(".BasicSweeper")


def sweep_jobs(overrides: Sequence[Override]) -> list[list[str]]:
    """The jobs Hydra's basic sweeper makes of `overrides`: every combination, in order, a
    later override of a key replacing an earlier one."""
    choices: dict[str, list[str]] = {}
    for override in overrides:
        key = override.get_key_element()
        if override.is_interval_sweep():
            raise InputError(f"{override.input_line}: an interval sweeps nothing here; list values")
        if override.is_sweep_override():
            choices[key] = [f"{key}={value}" for value in override.sweep_string_iterator()]
        else:
            choices[key] = [f"{key}={override.get_value_element_as_str()}"]
    return [list(job) for job in itertools.product(*choices.values())]


def recorded_job_count(sweep_dir: Path) -> int | None:
    """How many jobs the sweep last started in `sweep_dir` planned (`recorded_jobs`)."""
    jobs = recorded_jobs(sweep_dir)
    return None if jobs is None else len(jobs)


def recorded_jobs(sweep_dir: Path) -> list[list[str]] | None:
    """The jobs the sweep last started in `sweep_dir` planned, from its MULTIRUN_RECORD; None
    where that is missing or unreadable, or its sweeper is not the basic one."""
    try:
        hydra_cfg = OmegaConf.load(Path(sweep_dir) / MULTIRUN_RECORD).hydra
        if not _is_basic_sweeper(hydra_cfg):
            return None
        return planned_jobs([str(arg) for arg in hydra_cfg.overrides.task], hydra_cfg, True)
    except (OSError, yaml.YAMLError, HydraException, OmegaConfBaseException, InputError):
        return None  # a record that cannot be read: the caller goes on without it
    except (TypeError, AttributeError):
        return None  # a record of another shape


def _check_submit_commands(launcher: str) -> None:
    """A launcher that submits to a cluster needs its commands here (a login node's PATH)."""
    missing = [name for name in REMOTE_LAUNCHERS[launcher] if shutil.which(name) is None]
    if missing:
        raise InputError(
            f"hydra/launcher: {launcher.rsplit('.', 1)[-1]} submits with "
            f"{' and '.join(REMOTE_LAUNCHERS[launcher])}, but this machine has no "
            f"{' or '.join(missing)} on PATH: run the sweep from the cluster's login node"
        )


def parse_overrides(args: Sequence[str]) -> list[Override]:
    """Hydra's parse of override strings (its OverrideParseException on a syntax error)."""
    return OverridesParser.create().parse_overrides(list(args))

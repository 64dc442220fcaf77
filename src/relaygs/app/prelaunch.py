"""Check a `python -m relaygs.run` command line before Hydra starts any job.

Hydra reports unknown config names and composition problems in several lines, and a sweep
would only find a bad value when its job comes up. Here every config-group choice is checked
against the files in conf/, and every job the command would launch (the command-line sweeps
times the basic sweeper's `hydra.sweeper.params`) is composed and validated, so bad input
is one line before any work starts.
"""

from __future__ import annotations

import difflib
import importlib.util
import itertools
import re
import shutil
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml
from hydra import compose, initialize_config_dir
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from relaygs.app.plan import group_value_error
from relaygs.errors import InputError, one_line
from relaygs.paths import require_creatable_folder

MULTIRUN_FLAGS = frozenset({"-m", "--multirun"})
LAUNCH_FLAGS = MULTIRUN_FLAGS | {"-r", "--run"}
"""Flags that run jobs (the others print); Hydra reads them only before the overrides."""
MODE_FLAGS = {
    **{flag: "--run" for flag in ("-r", "--run")},
    **{flag: "--multirun" for flag in MULTIRUN_FLAGS},
    **{flag: "--cfg" for flag in ("-c", "--cfg")},
    **{flag: "--info" for flag in ("-i", "--info")},
    **{flag: "--shell-completion" for flag in ("-sc", "--shell-completion")},
}
"""Hydra's flags that choose what the command does, of which it takes one."""
CONFIG_LOCATION_FLAGS = frozenset(
    {"-cn", "--config-name", "-cp", "--config-path", "-cd", "--config-dir"}
)
"""Hydra flags that compose another config than conf/config.yaml (checked by Hydra alone)."""
BASIC_SWEEPER = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"
"""The `_target_` of Hydra's basic sweeper, whose jobs `sweep_jobs` lists (a name, not imported)."""
MULTIRUN_RECORD = "multirun.yaml"
"""What Hydra writes into a sweep folder: the sweep's config, its overrides included."""
LAUNCHER_PLUGINS = {
    "joblib": ("hydra_plugins.hydra_joblib_launcher", "hydra-joblib-launcher"),
    "submitit_local": ("hydra_plugins.hydra_submitit_launcher", "hydra-submitit-launcher"),
    "submitit_slurm": ("hydra_plugins.hydra_submitit_launcher", "hydra-submitit-launcher"),
    "slurm": ("hydra_plugins.hydra_submitit_launcher", "hydra-submitit-launcher"),
}
"""Launcher choices that need a plugin: (its module, its pip package). Others (Hydra's
`basic`, any installed plugin) are checked by composing."""
REMOTE_LAUNCHERS = {
    "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher": ("sbatch", "srun")
}
"""Launchers whose jobs run on other machines (a job's device is checked where it runs), with
the commands they submit through, which must be on this machine's PATH."""
GROUP_HINTS = {"scene": "; or set scene.path=DIR for a capture"}
CONFIG_NAME = "config"
HYDRA_CHOSEN_GROUPS = frozenset(
    f"hydra/{group}"
    for group in (
        "output",
        "launcher",
        "sweeper",
        "help",
        "hydra_help",
        "hydra_logging",
        "job_logging",
        "env",
    )
)
"""Groups of Hydra's own that its defaults always choose (a `+` would choose them twice)."""
UNQUOTED_ASCII_REFUSED = "~!#&;<>^`"
"""ASCII characters Hydra's override grammar reads in a value only inside its quotes (not the
brackets, which are its own syntax: lists, dicts, sweep functions such as `choice(1,2)`)."""
QUOTE_HINT = (
    "; a value with spaces needs shell quotes around the override ('scene.path=/data/my "
    f"scene'), one with non-ASCII characters or any of {UNQUOTED_ASCII_REFUSED} Hydra's "
    """quotes too: 'scene.path="~/data/scène"'"""
)
"""Added to a parse error when an override holds characters Hydra reads only when quoted, or
is a bare word (a path with a space the shell split in two)."""

JobValidator = Callable[[DictConfig, bool], None]
"""Raises InputError when a composed job config is bad; the flag says whether the job runs on
this machine, so that what it needs from the machine (its device) can be checked here."""


SYNTHETIC_ONLY = (
    "scene",
    "scene.preset",
    "scene.frames",
    "scene.width",
    "scene.height",
    "scene.seed",
)
"""Overrides that only a synthetic scene takes: a capture (`scene.path`) has its own."""


def check_command_line(argv: Sequence[str], conf_dir: Path, validate: JobValidator) -> None:
    """Raise a one-line InputError if the command line names an unknown config, does not
    compose, would launch a job whose config `validate` rejects, or names a run (sweep) folder
    that cannot be written.

    With Hydra's other flags (--help, --cfg job, --info ...) the command prints rather than
    runs: only its overrides are checked, that they parse, name known configs and compose.
    Flags that choose another config (-cn, -cp, -cd) and shell completion (-sc) leave the whole
    check to Hydra.
    """
    flags = [arg for arg in argv if arg.startswith("-")]
    modes = _chosen_modes(flags)
    if "--shell-completion" in modes or any(
        flag.split("=")[0] in CONFIG_LOCATION_FLAGS for flag in flags
    ):
        return  # `-sc install=bash` is Hydra's own command, not an override
    if any(flag not in LAUNCH_FLAGS for flag in flags):
        _check_printing_command([arg for arg in argv if _is_override(arg)], conf_dir)
        return
    _check_launching_command(
        [arg for arg in argv if not arg.startswith("-")], conf_dir, "--multirun" in modes, validate
    )


def _chosen_modes(flags: Sequence[str]) -> list[str]:
    """The long names of the mode flags given (--run, --multirun, --cfg ...); more than one
    is refused, as Hydra takes one."""
    modes = sorted(
        {MODE_FLAGS[name] for name in (f.split("=")[0] for f in flags) if name in MODE_FLAGS}
    )
    if len(modes) > 1:
        raise InputError(
            f"{' and '.join(modes)} cannot be combined: Hydra takes one of "
            f"{', '.join(dict.fromkeys(MODE_FLAGS.values()))}"
        )
    return modes


def _check_launching_command(
    args: list[str], conf_dir: Path, multirun_flag: bool, validate: JobValidator
) -> None:
    """Every job a running command would launch composes and passes `validate`, a remote
    launcher's submit commands exist, and the run (sweep) folder can be written."""
    overrides = parse_overrides(args)
    check_group_choices(overrides, conf_dir)
    groups = [group for group in primary_groups(conf_dir) if "/" not in group]
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3", job_name="run"):
        plain = [o.input_line for o in overrides if not o.is_sweep_override()]
        hydra_cfg = _compose_explained(plain, conf_dir, with_hydra=True).hydra
        # --run does not override a config's `hydra.mode: MULTIRUN`; --multirun does
        multirun = multirun_flag or hydra_cfg.mode == RunMode.MULTIRUN
        launcher = hydra_cfg.launcher.get("_target_")
        runs_here = not multirun or launcher not in REMOTE_LAUNCHERS
        if not runs_here:
            _check_submit_commands(launcher)
        jobs = planned_jobs(args, overrides, hydra_cfg, multirun)
        swept = swept_keys(jobs)
        for job in jobs:
            try:
                check_capture_overrides(job)
                check_group_choices(
                    parse_overrides(job), conf_dir
                )  # a choice swept by an experiment
                config = _compose_explained(job, conf_dir)
                check_group_sections(config, groups, hydra_cfg.runtime.choices.get("experiment"))
                validate(config, runs_here)
            except InputError as error:
                named = [arg for arg in job if arg.partition("=")[0] in swept] or job
                where = f"job {' '.join(named)}: " if job != args else ""
                raise InputError(f"{where}{error}") from error
        check_output_folder(hydra_cfg, multirun)  # after the jobs' own paths, often its parents


def swept_keys(jobs: Sequence[Sequence[str]]) -> set[str]:
    """The override keys whose value differs between `jobs` (a sweep's axes): what names a
    job among the others, as `job relay.k=0`."""
    values: dict[str, set[str]] = {}
    for job in jobs:
        for arg in job:
            key, _, value = arg.partition("=")
            values.setdefault(key, set()).add(value)
    return {key for key, seen in values.items() if len(seen) > 1}


def check_capture_overrides(job: Sequence[str]) -> None:
    """A job that reads a capture (`scene.path=DIR`) must not also set what only a synthetic
    preset has (the preset, its frame count, image size or generator seed): the capture would
    ignore it, though the result would record it. A deleted (`~scene.path`), null or empty
    path reads none (an empty one is refused as no path later)."""
    settings = {
        o.key_or_group: o for o in parse_overrides(job)
    }  # the last override of a key counts
    path = settings.get("scene.path")
    if path is None or path.is_delete() or path.value() in (None, ""):
        return
    ignored = [o for key, o in settings.items() if key in SYNTHETIC_ONLY and not o.is_delete()]
    if ignored:
        raise InputError(
            f"{ignored[0].input_line.lstrip('+')} sets a synthetic scene, but scene.path reads "
            "a capture, whose frames, size and cameras are its own: drop one of the two "
            "(a capture's options are scene.loader.*)"
        )


def _is_override(arg: str) -> bool:
    """Whether a command-line word is a Hydra override (`key=value`, `+key=...`, `~key`) and
    not a flag or a flag's value (`--cfg job`, `--info defaults`)."""
    return not arg.startswith("-") and ("=" in arg or arg.startswith("~"))


def _check_printing_command(args: list[str], conf_dir: Path) -> None:
    """The overrides of a command that only prints (--cfg, --info, --help) parse, name known
    configs and compose; sweeps are composed with their first value as Hydra would show."""
    overrides = parse_overrides(args)
    check_group_choices(overrides, conf_dir)
    plain = [o.input_line for o in overrides if not o.is_sweep_override()]
    with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3", job_name="run"):
        _compose_explained(plain, conf_dir)


def check_group_choices(overrides: Sequence[Override], conf_dir: Path) -> None:
    """Every `group=name` override of a group in conf/ must name one of its files; groups that
    neither the main defaults list nor the chosen experiment's choose need `+`, the others take
    none; a launcher's plugin must be installed."""
    chosen = _experiment_groups(overrides, conf_dir)
    primary = primary_groups(conf_dir) | HYDRA_CHOSEN_GROUPS | chosen
    for override in overrides:
        group = override.key_or_group
        named = isinstance(override.value(), str) or override.is_sweep_override()
        if group in primary and override.is_add() and named:  # Hydra: "Multiple values for"
            raise InputError(
                f"{group} is chosen already (by the main config or the experiment): write "
                f"{override.input_line.removeprefix('+')} (without the +)"
            )
        if group == "hydra/launcher" and not override.is_delete():
            for choice in _choices(override):
                _check_launcher_plugin(choice)
            continue
        if override.is_delete() or not (conf_dir / group).is_dir():
            continue
        for choice in _choices(override):
            available = available_choices(conf_dir, group)
            if choice not in available:
                raise InputError(
                    f"unknown {group} {choice!r} (available: {', '.join(available)})"
                    f"{GROUP_HINTS.get(group, '')}"
                )
        if group not in primary and not override.is_add():
            raise InputError(
                f"{group} is not chosen by default: write +{group}={override.value()} "
                f"(with a leading +)"
            )


def _experiment_groups(overrides: Sequence[Override], conf_dir: Path) -> set[str]:
    """The groups of conf/ that the defaults lists of the experiments `overrides` choose
    (`- /component: full`): a command line then picks another file of them without `+`."""
    groups: set[str] = set()
    for override in overrides:
        if override.key_or_group == "experiment" and not override.is_delete():
            for name in _choices(override):
                groups |= _defaults_entries(conf_dir / "experiment" / f"{name}.yaml").keys()
    return groups


def check_group_sections(
    config: DictConfig, groups: Sequence[str], experiment: str | None = None
) -> None:
    """Each config group of `groups` holds a section: an experiment file that sets one to a
    value (`pipeline: 4dgs`) is refused in one line naming the group, the `override` that
    chooses its file and the `experiment` file chosen, if any, before the value breaks an
    interpolation (`${pipeline.name}`)."""
    values = OmegaConf.to_container(config, resolve=False)
    for group in sorted(groups):
        if not isinstance(values.get(group), Mapping):
            chosen = (
                f" (the experiment chosen: conf/experiment/{experiment}.yaml)" if experiment else ""
            )
            raise InputError(group_value_error(group, values.get(group)) + chosen)


def _compose_explained(args: Sequence[str], conf_dir: Path, with_hydra: bool = False) -> DictConfig:
    """`_compose`, whose failure is first checked for its cause in the group choices alone
    (`_check_choices_alone`)."""
    try:
        return _compose(args, conf_dir, with_hydra)
    except InputError:
        _check_choices_alone(args, conf_dir)
        raise


def _check_choices_alone(args: Sequence[str], conf_dir: Path) -> None:
    """`check_group_sections` on the config of the group choices among `args` alone: an
    experiment that sets a group to a value (`scene: court`) makes each override inside that
    group (`scene.frames=8`) fail to compose, which the group's own line explains."""
    groups = [group for group in primary_groups(conf_dir) if "/" not in group]
    choices = [
        o.input_line for o in parse_overrides(args) if o.is_add() or o.key_or_group in groups
    ]
    try:
        config = _compose(choices, conf_dir, with_hydra=True)
    except InputError:
        return  # the choices fail alone too: the composition's own line says why
    experiment = config.hydra.runtime.choices.get("experiment")
    check_group_sections(config, groups, experiment)


def check_output_folder(hydra_cfg: DictConfig, multirun: bool) -> None:
    """The run folder (`hydra.run.dir`, or `hydra.sweep.dir` for a multirun) must be a folder
    that files can be written in, or one that can be created."""
    key = "sweep" if multirun else "run"
    text = str(hydra_cfg[key].dir)
    if not text.strip():
        # Path("") is the folder the command started in, which would get the run's files
        raise InputError(f"hydra.{key}.dir: expected a path (a non-empty string), got {text!r}")
    folder = Path(text).expanduser().absolute()
    require_creatable_folder(folder, f"hydra.{key}.dir")


def planned_jobs(
    args: list[str], overrides: Sequence[Override], hydra_cfg: DictConfig, multirun: bool
) -> list[list[str]]:
    """The override lists of the jobs this command line would run (one in run mode), given the
    composed `hydra` section and whether this is a multirun."""
    plain = [o.input_line for o in overrides if not o.is_sweep_override()]
    sweeps = [o.input_line for o in overrides if o.is_sweep_override()]
    if not multirun:
        if sweeps:
            raise InputError(
                f"{sweeps[0]} lists several values: add --multirun (-m) to sweep over them, "
                "or write a list as key=[a,b]"
            )
        return [args]
    if hydra_cfg.sweeper.get("_target_") != BASIC_SWEEPER:
        return [plain]
    params = [f"{key}={value}" for key, value in (hydra_cfg.sweeper.get("params") or {}).items()]
    return sweep_jobs(parse_overrides([*params, *args]))


def sweep_jobs(overrides: Sequence[Override]) -> list[list[str]]:
    """The jobs Hydra's basic sweeper makes of `overrides`: every combination of the values of
    each key, in order, a later override of a key replacing an earlier one (the command line
    over `hydra.sweeper.params`)."""
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
    """The override lists of the jobs the sweep last started in `sweep_dir` planned, from the
    MULTIRUN_RECORD Hydra writes there before its first job; None where that file is missing
    or unreadable, or its sweeper is not Hydra's basic one (whose jobs this cannot list)."""
    try:
        hydra_cfg = OmegaConf.load(Path(sweep_dir) / MULTIRUN_RECORD).hydra
        if hydra_cfg.sweeper.get("_target_") != BASIC_SWEEPER:
            return None
        task = [str(arg) for arg in hydra_cfg.overrides.task]
        return planned_jobs(task, parse_overrides(task), hydra_cfg, multirun=True)
    except (OSError, yaml.YAMLError, OmegaConfBaseException, InputError, TypeError, AttributeError):
        return None  # a record that cannot be read: the caller goes on without it


def primary_groups(conf_dir: Path) -> set[str]:
    """Groups the main config's defaults list chooses (the others need `+group=`)."""
    return set(_defaults_entries(conf_dir / f"{CONFIG_NAME}.yaml"))


def available_choices(conf_dir: Path, group: str) -> list[str]:
    """The config names of a group folder (files starting with `_` are not choices)."""
    return sorted(
        path.stem for path in (conf_dir / group).glob("*.yaml") if not path.stem.startswith("_")
    )


def _check_submit_commands(launcher: str) -> None:
    """A launcher that submits to a cluster needs its commands here (a login node's PATH)."""
    missing = [name for name in REMOTE_LAUNCHERS[launcher] if shutil.which(name) is None]
    if missing:
        raise InputError(
            f"hydra/launcher: {launcher.rsplit('.', 1)[-1]} submits with "
            f"{' and '.join(REMOTE_LAUNCHERS[launcher])}, but this machine has no "
            f"{' or '.join(missing)} on PATH: run the sweep from the cluster's login node"
        )


def _check_launcher_plugin(choice: str) -> None:
    """A launcher that comes from a plugin needs that plugin installed."""
    module, package = LAUNCHER_PLUGINS.get(choice, ("", ""))
    if module and not is_installed(module):
        raise InputError(
            f"hydra/launcher={choice} needs the {package} plugin: pip install {package}"
        )


def is_installed(module: str) -> bool:
    """True when `module` (dotted) can be imported; a missing parent package counts as not."""
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def _choices(override: Override) -> list[str]:
    """The option names an override selects (each value of a sweep)."""
    if override.is_sweep_override():
        return list(override.sweep_string_iterator()) if override.is_discrete_sweep() else []
    return [str(override.value())]


def parse_overrides(args: Sequence[str]) -> list[Override]:
    """Parse override strings; a syntax error becomes one line (with how to quote a value, when
    an override holds characters Hydra reads only inside quotes)."""
    try:
        return OverridesParser.create().parse_overrides(list(args))
    except HydraException as error:
        hint = "" if all(_needs_no_quotes(arg) for arg in args) else QUOTE_HINT
        raise InputError(f"cannot parse overrides: {one_line(error)}{hint}") from error


def _needs_no_quotes(arg: str) -> bool:
    """True for an override Hydra can read as typed: `key=value` (or `~key`) in ASCII, with no
    space and none of UNQUOTED_ASCII_REFUSED in the value."""
    if arg.startswith("~") and "=" not in arg:
        return arg.isascii() and " " not in arg
    _, equals, value = arg.partition("=")
    refused = any(char in UNQUOTED_ASCII_REFUSED for char in value)
    return bool(equals) and arg.isascii() and " " not in arg and not refused


def _compose(overrides: Sequence[str], conf_dir: Path, with_hydra: bool = False) -> DictConfig:
    """Compose the main config (of `conf_dir`, initialised by the caller) with `overrides`;
    composition errors become one line."""
    try:
        return compose(CONFIG_NAME, overrides=list(overrides), return_hydra_config=with_hydra)
    except (HydraException, OmegaConfBaseException) as error:
        raise InputError(_composition_error(error, overrides, conf_dir)) from error


EXPERIMENT_GROUP_ERRORS = (
    r"^In 'experiment/[^']+': Could not find 'experiment/(?P<group>[\w/]+)/(?P<choice>[^']+)'",
    r"^In 'experiment/[^']+': Could not override 'experiment/(?P<group>[\w/]+)@(?P=group)'",
    r"^In 'experiment/[^']+': Could not override '(?P<group>[\w/]+)'\. No match in the defaults",
)
"""Hydra's errors for a group chosen wrongly in an experiment's defaults list, which only the
experiment file can cause: without the `/` (`pipeline: 4dgs`, read as a group inside
conf/experiment/), or `override` with no slash or for a group the main config does not
choose (`override pipeline: 4dgs`, `override /component: full`)."""
SHARED_GROUP_ERRORS = (
    r"Multiple values for (?P<group>[\w/]+)\. To override a value use 'override "
    r"(?P=group): (?P<choice>[^']+)'",
    r"Could not find '(?P<group>[\w/]+)/(?P<choice>[^']+)'\s+Available options",
    r"^(?P<group>[\w/]+) appears more than once in the final defaults list",
)
"""Hydra's errors that an experiment's defaults list causes when it chooses a group the main
config chooses without `override` (`/pipeline: 4dgs`; "appears more than once" where the
command line chooses it too), or a file the group lacks; another config can cause them too."""


def _experiment_defaults_error(
    error: Exception, overrides: Sequence[str], conf_dir: Path
) -> str | None:
    """The line for a group chosen wrongly in the defaults list of the experiment `overrides`
    choose (EXPERIMENT_GROUP_ERRORS; SHARED_GROUP_ERRORS where the experiment's defaults list
    chooses the group), naming the file and the entry to write; None for any other error, and
    for Hydra's own groups. (A `+group=` of a chosen group on the command line, the other cause
    of "Multiple values", is refused before composing: `check_group_choices`.)"""
    parsed = parse_overrides(overrides)
    experiment = next((o for o in parsed if o.key_or_group == "experiment"), None)
    if experiment is None:
        return None
    path = conf_dir / "experiment" / f"{experiment.value()}.yaml"
    entries = _defaults_entries(path)
    found = _first_match(EXPERIMENT_GROUP_ERRORS, str(error))
    shared = _first_match(SHARED_GROUP_ERRORS, str(error))
    if found is None and shared is not None and shared["group"] in entries:
        found = shared
    if found is None or found["group"].startswith("hydra/"):
        return None
    group = found["group"]
    chosen = entries.get(group)
    choice = found.groupdict().get("choice") or (chosen if isinstance(chosen, str) else None)
    where = f"conf/experiment/{experiment.value()}.yaml"
    available = available_choices(conf_dir, group)
    if choice is not None and choice not in available:
        return (
            f"{where}: its defaults list chooses an unknown {group} {choice!r} "
            f"(available: {', '.join(available)})"
        )
    primary = group in primary_groups(conf_dir)
    entry = f"{'override ' if primary else ''}/{group}: {choice or '<name>'}"
    return (
        f"{where}: its defaults list must choose the {group} group as `- {entry}` (a group of "
        "conf/ is named with a leading slash"
        + (", and one the main config chooses needs `override`)" if primary else ")")
    )


def _first_match(patterns: Sequence[str], text: str) -> re.Match[str] | None:
    """The match of the first of `patterns` found in `text`, if any."""
    return next(filter(None, (re.search(pattern, text) for pattern in patterns)), None)


def _defaults_entries(path: Path) -> dict[str, Any]:
    """{group: choice} of the entries of the defaults list in the YAML file `path`, however an
    entry names its group (`pipeline`, `/pipeline`, `override pipeline`); empty when the file
    cannot be read (the main config's, or an experiment's)."""
    try:
        defaults = yaml.safe_load(path.read_text(encoding="utf-8")).get("defaults")
    except (OSError, UnicodeDecodeError, yaml.YAMLError, AttributeError):
        return {}
    return {
        str(key).removeprefix("override").strip().lstrip("/"): value
        for entry in (defaults if isinstance(defaults, list) else [])
        for key, value in (entry.items() if isinstance(entry, dict) else [])
    }


def _composition_error(error: Exception, overrides: Sequence[str], conf_dir: Path) -> str:
    """The one line for a failed composition. Hydra answers an override of a key the config
    lacks (`relay.kk=8`, or `scene.loader={zoom:2}`) with advice to append it, which every
    section but `hydra` then refuses, and a value of the wrong kind (`deform.multires={a:1}`)
    with "Error merging override": such an override gets `_unknown_setting`'s or
    `_kind_mismatch`'s line instead, from the config composed without it."""
    experiment_line = _experiment_defaults_error(error, overrides, conf_dir)
    if experiment_line is not None:
        return experiment_line
    found = re.match(r"Could not override '([^']+)'|Error merging override ([^=]+)=", str(error))
    if found is None:
        return one_line(error)
    key = (found[1] or found[2]).lstrip("+")  # `+key=` and `++key=` name the key
    parsed = parse_overrides(overrides)
    given = next((o.value() for o in parsed if o.key_or_group == key), None)
    others = [o.input_line for o in parsed if o.key_or_group != key]
    try:
        config = compose(CONFIG_NAME, overrides=others, return_hydra_config=True)
    except (HydraException, OmegaConfBaseException):
        return one_line(error)
    container = OmegaConf.to_container(config)
    line = _unknown_setting(container, key) or _kind_mismatch(container, key, given)
    return line or one_line(error)


def _kind_mismatch(config: Mapping[str, Any], key: str, given: Any) -> str | None:
    """What is wrong with giving the config's dotted `key` the value `given`: a kind other than
    the config's (a mapping for a list), or, for a mapping, the first setting inside it that
    the section lacks. None when neither (the error is Hydra's to tell)."""
    current: Any = config
    for part in key.split("."):
        if not isinstance(current, Mapping) or part not in current:
            return None  # a `hydra.*` key to append: `_unknown_setting` leaves those alone
        current = current[part]
    if isinstance(current, Mapping) and isinstance(given, Mapping):
        for name, value in given.items():
            inner = f"{key}.{name}"
            line = _unknown_setting(config, inner) or _kind_mismatch(config, inner, value)
            if line:
                return line
        return None
    if _kind(current) != _kind(given):
        return f"{key}: expected {_kind(current)}, as in the config, got {given!r}"
    return None


def _kind(value: Any) -> str:
    """How a config value is shaped: a section, a list or a single value."""
    if isinstance(value, Mapping):
        return "a section of settings"
    return "a list" if isinstance(value, list) else "a single value"


def _unknown_setting(config: Mapping[str, Any], key: str) -> str | None:
    """What is wrong with setting the dotted `key` that `config` lacks: the section that has no
    such part, and the nearest keys (`did you mean relay.k?`; one level down too, so
    `scene.test_cameras` finds `scene.loader.test_cameras`), else the section's keys; or that
    a part of the way is a value. None where appending may be meant (a `hydra.*` key that is
    no typo)."""
    parts = key.split(".")
    node: Any = config
    depth = 0
    while depth < len(parts) and isinstance(node, Mapping) and parts[depth] in node:
        node, depth = node[parts[depth]], depth + 1
    if depth == len(parts):
        return None
    if not isinstance(node, Mapping):  # `relay.k.x`: a value, where a section was taken
        value = ".".join(parts[:depth])
        return None if parts[0] == "hydra" else f"{key}: {value} is a value, not a section"
    section, missing = ".".join(parts[:depth]), parts[depth]
    lacks = f"{key}: {section or 'the config'} has no setting '{missing}'"
    nearest = _nearest_keys(node, missing)
    if nearest:
        tail = "".join(f".{part}" for part in parts[depth + 1 :])
        guesses = " or ".join(".".join(filter(None, (section, near))) + tail for near in nearest)
        return f"{lacks}; did you mean {guesses}?"
    if parts[0] == "hydra":
        return None
    return f"{lacks} (it has {', '.join(sorted(map(str, node)))})"


def _nearest_keys(section: Mapping[str, Any], name: str) -> list[str]:
    """The key of `section` closest to `name` (difflib), else the `child.key` paths one level
    down whose key is closest; empty when nothing is close."""
    close = difflib.get_close_matches(name, [str(key) for key in section], n=1)
    if close:
        return close
    below = {
        f"{child}.{key}": str(key)
        for child, value in section.items()
        if isinstance(value, Mapping)
        for key in value
    }
    close = difflib.get_close_matches(name, set(below.values()), n=1)
    return [path for path, key in below.items() if close and key == close[0]]

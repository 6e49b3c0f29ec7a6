"""A bad argument or input as one line, ``error: ...``, exit status 2: the checks of the
command line's words before it is parsed (``--config`` files, ``--model``/``--data`` import
paths), and which errors are the user's (``USER_ERRORS``), even raised in a DataLoader worker."""

from __future__ import annotations

import builtins
import importlib
import os
import re
import stat
import traceback
from collections.abc import Callable
from pathlib import Path

import yaml
from lightning.fabric.utilities.exceptions import MisconfigurationException

from voe_lightning.class_paths import import_failure, import_object

#: Environment variable that, like ``--debug`` anywhere on the command line, shows the traceback
#: of a refused argument or input instead of its one-line error.
DEBUG_VARIABLE = "VOE_DEBUG"
#: Errors that mean a bad argument or input, or a run that cannot go on (a non-finite loss,
#: ``SurpriseModel._check_finite``): printed as one line, exit status 2.
USER_ERRORS = (ValueError, OSError, MisconfigurationException, FloatingPointError)
#: The most values a ``--config`` file may expand to through its YAML aliases (a paper config
#: holds a few hundred; nested anchors can make 700 bytes hold 10^9, which would hang).
MAX_CONFIG_VALUES = 100_000
#: The largest ``--config`` file read (the package's configs hold under 5 KB).
MAX_CONFIG_BYTES = 1 << 20
#: What a path that is no regular file or folder is, by its ``stat`` mode.
FILE_KINDS = (
    (stat.S_ISFIFO, "a pipe (FIFO)"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)
#: Flags whose value may be a class's import path, with an example of one.
CLASS_FLAGS = {"--model": "voe_lightning.model.VRNNLRUModel", "--data": "my_package.MyDataModule"}
#: How torch's DataLoader re-raises in this process an error a worker process raised: the
#: worker's whole traceback as its message, whose last line is "module.Type: message".
WORKER_ERROR = re.compile(
    r"Caught \w+ in DataLoader worker process \d+\.\n"
    r"Original Traceback \(most recent call last\):\n.*\n"
    r"(?P<type>[\w.]+): (?P<message>.*?)\n?\Z",
    re.S,
)


def check_yaml(words: list[str]) -> None:
    """Refuse a ``--config`` file that is not valid YAML, naming it (jsonargparse's message
    gives the line and column of "<unicode string>"), or that expands to more than
    ``MAX_CONFIG_VALUES`` values through its aliases."""
    for _, index, prefix in _flag_values(words, _is_config_flag):
        name = words[index][len(prefix) :]
        text = _config_text(name)
        if text is None:
            continue  # the parser names a missing file itself
        try:
            document = yaml.compose(text, Loader=yaml.SafeLoader)
        except yaml.YAMLError as error:
            mark = getattr(error, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(error, "problem", None) or error
            raise ValueError(f"--config {name} is not valid YAML{where}: {problem}") from None
        if document is None or (
            isinstance(document, yaml.ScalarNode) and document.tag.endswith(":null")
        ):
            raise ValueError(
                f"--config {name} is empty (or null): a config is a YAML mapping of arguments, "
                "e.g. 'trainer: {max_steps: 100}'; give one, or leave this --config out"
            )
        if not isinstance(document, yaml.MappingNode):
            kind = "a list" if isinstance(document, yaml.SequenceNode) else "a single value"
            raise ValueError(
                f"--config {name} holds {kind}, not a mapping of arguments: a config is a "
                "YAML mapping, e.g. 'trainer: {max_steps: 100}'"
            )
        if _expanded_size(document, {}) > MAX_CONFIG_VALUES:
            raise ValueError(
                f"--config {name} expands to more than {MAX_CONFIG_VALUES:,} values "
                "through its YAML aliases (*name repeating &name): refused; a "
                "config needs no more"
            )


def _is_config_flag(flag: str) -> bool:
    """Whether ``flag`` is ``--config``: ``-c`` too, and the prefixes argparse takes for it."""
    return flag == "-c" or (len(flag) > 3 and "--config".startswith(flag))


def _flag_values(words: list[str], is_flag: Callable[[str], bool]) -> list[tuple[str, int, str]]:
    """Each value among ``words`` of a flag ``is_flag`` accepts (``--flag V`` or ``--flag=V``):
    the flag, the value's index, and the prefix before it in that word (``--flag=``; '' for a
    value that is a word of its own)."""
    values = []
    for index, word in enumerate(words):
        flag, equals, _ = word.partition("=")
        if is_flag(flag):
            if equals:
                values.append((flag, index, flag + equals))
            elif index + 1 < len(words):
                values.append((flag, index + 1, ""))
    return values


def shipped_config_names(words: list[str], shipped: Path) -> list[str]:
    """``words`` with each ``--config NAME`` that names no file but one of the configs in
    ``shipped`` (``quickstart``, ``overlays/untrained_null``; ``.yaml`` may be left out)
    replaced by that config's path, so a config is given by name wherever the package is
    installed; a name that is neither is refused, listing the shipped ones."""
    words = list(words)
    for _, index, prefix in _flag_values(words, _is_config_flag):
        name = words[index][len(prefix) :]
        if not name or Path(name).exists():
            continue  # the parser names an empty or missing file itself
        config = shipped / (name if name.endswith((".yaml", ".yml")) else f"{name}.yaml")
        if config.is_file():
            words[index] = prefix + str(config)
        elif "/" not in name and not name.endswith((".yaml", ".yml")):
            names = sorted(
                str(path.relative_to(shipped).with_suffix("")) for path in shipped.rglob("*.yaml")
            )
            raise ValueError(
                f"--config {name} is neither a file nor a config the package ships; give a "
                f"YAML file's path or one of: {', '.join(names)}"
            )
    return words


def _config_text(name: str) -> str | None:
    """A ``--config`` file's text, its type and size checked before it is opened (a folder, a
    pipe or device, a file over ``MAX_CONFIG_BYTES`` refused); None when it cannot be read."""
    try:
        status = os.stat(name)
    except OSError:
        return None
    if stat.S_ISDIR(status.st_mode):
        found = sorted(Path(name).glob("*.yaml"))
        raise ValueError(
            f"--config {name} is a directory, not a YAML file; give one file"
            + (f", e.g. {found[0]}" if found else "")
        )
    if not stat.S_ISREG(status.st_mode):
        kind = next((k for is_kind, k in FILE_KINDS if is_kind(status.st_mode)), "a special file")
        raise ValueError(
            f"--config {name} is {kind}, not a regular file: give a YAML file (a pipe, "
            "device or /dev/stdin would be read whole before the parser reads it again)"
        )
    if status.st_size > MAX_CONFIG_BYTES:
        raise ValueError(
            f"--config {name} is {status.st_size:,} bytes, more than the {MAX_CONFIG_BYTES:,} "
            "a config may be (the package's own are under 5 KB): give a YAML config file"
        )
    try:
        return Path(name).read_text()
    except OSError:
        return None


def check_classes(words: list[str]) -> None:
    """Refuse a ``--model``/``--data`` import path (``package.module.Class``; not a file)
    that cannot be imported, naming it and why, which the parser's message leaves out for a
    command's own parser (``check-causality``) and, as the error's type, for a module that
    raised as it was imported. (An abstract class the parser refuses: ``parser_errors``.)"""
    for flag, index, prefix in _flag_values(words, CLASS_FLAGS.__contains__):
        value = words[index][len(prefix) :]
        if (
            not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", value)
            or Path(value).exists()
            or Path(value).suffix in (".yaml", ".yml", ".json")
        ):
            continue
        try:
            import_object(value)
        except Exception as error:  # any error importing it: the module's own too
            raise ValueError(
                f"{flag} {value} cannot be imported ({import_failure(error)}); give a class's "
                f"import path, e.g. {CLASS_FLAGS[flag]}"
            ) from error


def _expanded_size(node: yaml.Node, sizes: dict[int, int]) -> int:
    """How many values the YAML ``node`` holds with every alias expanded, counted once per
    distinct node (``sizes``: by id), so a billion-value alias bomb costs microseconds."""
    if id(node) not in sizes:
        sizes[id(node)] = 1  # a node that contains itself counts once
        children = (
            [part for pair in node.value for part in pair]
            if isinstance(node, yaml.MappingNode)
            else node.value
            if isinstance(node, yaml.SequenceNode)
            else []
        )
        sizes[id(node)] = 1 + sum(_expanded_size(child, sizes) for child in children)
    return sizes[id(node)]


def user_message(error: BaseException) -> str | None:
    """The message of the error the user's value caused (None: not one of ``USER_ERRORS``, a
    bug whose traceback shows): jsonargparse wraps a class's ValueError in one of its own
    that lists every type it tried, so unwrap those; a DataLoader worker's error is the
    worker's own one line, as in the main process (torch re-raises it with the worker's
    traceback as its message, or as a RuntimeError where its type takes other arguments)."""
    while error.__cause__ is not None and _raised_in(error, "jsonargparse"):
        error = error.__cause__
    worker = WORKER_ERROR.match(str(error.args[0]) if error.args else "")
    if worker is None:
        return str(error) if isinstance(error, USER_ERRORS) else None
    module, _, name = worker["type"].rpartition(".")
    try:
        original = getattr(importlib.import_module(module) if module else builtins, name, None)
    except ImportError:
        original = None
    if isinstance(original, type) and issubclass(original, USER_ERRORS):
        return worker["message"]
    return None


def _raised_in(error: BaseException, package: str) -> bool:
    """Whether ``error`` was raised by code of ``package``."""
    frames = traceback.extract_tb(error.__traceback__)
    return bool(frames) and f"{os.sep}{package}{os.sep}" in frames[-1].filename

"""A bad argument or input as one line, ``error: ...``, exit 2: the command line's ``--config``
files and import paths checked before parsing, and which errors are the user's (``USER_ERRORS``)."""

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
from voe_lightning.cli.parser_errors import EXAMPLES, cannot_import

#: Environment variable that, like ``--debug``, shows a refusal's traceback instead of its line.
DEBUG_VARIABLE = "VOE_DEBUG"
#: Errors of a bad argument or input, or of a run that cannot go on (a non-finite loss): one line.
USER_ERRORS = (ValueError, OSError, MisconfigurationException, FloatingPointError)
#: The most values a ``--config`` may expand to through YAML aliases (700 bytes can hold 10^9).
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
CLASS_FLAGS = {f"--{section}": example for section, example in EXAMPLES.items()}
#: A DataLoader worker's error as torch re-raises it: the worker's traceback, last "Type: message".
WORKER_ERROR = re.compile(
    r"Caught \w+ in DataLoader worker process \d+\.\n"
    r"Original Traceback \(most recent call last\):\n.*\n"
    r"(?P<type>[\w.]+): (?P<message>.*?)\n?\Z",
    re.S,
)


def check_yaml(words: list[str]) -> None:
    """Refuse a ``--config`` file that is not a YAML mapping, naming it (jsonargparse names
    "<unicode string>"), or that expands to over ``MAX_CONFIG_VALUES`` values through aliases."""
    for *_, name in _flag_values(words, _is_config_flag):
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


def _flag_values(
    words: list[str], is_flag: Callable[[str], bool]
) -> list[tuple[str, int, str, str]]:
    """Each value of a flag ``is_flag`` accepts among ``words`` (``--flag V``, ``--flag=V``): the
    flag, the index of the value's word, the prefix before it there ('' or ``--flag=``), itself."""
    values = []
    for index, word in enumerate(words):
        flag, equals, value = word.partition("=")
        if is_flag(flag):
            if equals:
                values.append((flag, index, flag + equals, value))
            elif index + 1 < len(words):
                values.append((flag, index + 1, "", words[index + 1]))
    return values


def shipped_config_names(words: list[str], shipped: Path) -> list[str]:
    """``words`` with each ``--config NAME`` of a config in ``shipped`` (``quickstart``; no file
    of that name) as its path, wherever the package is installed; an unknown name refused."""
    words = list(words)
    for _, index, prefix, name in _flag_values(words, _is_config_flag):
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
    """Refuse a ``--model``/``--data`` import path that does not import, saying why (the parser
    does not for ``check-causality``'s, nor the type of a module's own error)."""
    for flag, _, _, value in _flag_values(words, CLASS_FLAGS.__contains__):
        if (
            not re.fullmatch(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)+", value)
            or Path(value).exists()
            or Path(value).suffix in (".yaml", ".yml", ".json")
        ):
            continue
        try:
            import_object(value)
        except Exception as error:  # any error importing it: the module's own too
            raise ValueError(cannot_import(flag, value, import_failure(error), flag[2:])) from error


def _expanded_size(node: yaml.Node, sizes: dict[int, int]) -> int:
    """How many values the YAML ``node`` holds with every alias expanded, counted once per
    distinct node (``sizes``: by id), so a billion-value alias bomb costs microseconds."""
    if id(node) not in sizes:
        sizes[id(node)] = 1  # a node that contains itself counts once
        children = node.value if isinstance(node, yaml.SequenceNode) else []
        if isinstance(node, yaml.MappingNode):
            children = [part for pair in node.value for part in pair]
        sizes[id(node)] = 1 + sum(_expanded_size(child, sizes) for child in children)
    return sizes[id(node)]


def user_message(error: BaseException) -> str | None:
    """The message of a ``USER_ERRORS`` error (None: a bug, whose traceback shows), unwrapped
    from jsonargparse's wrappers and from a DataLoader worker's traceback (``WORKER_ERROR``)."""
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

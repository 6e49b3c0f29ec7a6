"""The parser's refusals as one line (``one_line``): the argument, the value and what would be
valid, not jsonargparse's usage and nested message, which ``--debug`` prints (``full_messages``)."""

from __future__ import annotations

import ast
import contextlib
import inspect
import re
import sys
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Any, NoReturn

from voe_lightning.class_paths import import_failure, import_object, missing_methods

#: Whether the parser prints its own usage and nested message (``--debug``).
_FULL_MESSAGES: ContextVar[bool] = ContextVar("full_parser_messages", default=False)
#: An example class path for the sections that take one (``--model``, ``--data``).
EXAMPLES = {"model": "voe_lightning.model.VRNNLRUModel", "data": "my_package.MyDataModule"}
#: Union alternatives that explain nothing when another one failed (None, a config file's path).
_OTHER_ALTERNATIVES = re.compile(
    r"Expected a <class 'NoneType'>|Expected a path but|Expected a <class 'bool'>"
)
_KEY = re.compile(r'Parser key "(?P<key>[^"]+)":\s*(?P<rest>.*)')
_CLASS_PATH = re.compile(r"Problem with given class_path '(?P<class_path>[^']+)':\s*(?P<rest>.*)")
_TYPE = re.compile(r"Expected an? (?P<type>.+?)\. Got value: (?P<value>.*)")
_EXPECTED = re.compile(r"Expected an? (?P<type><class '[^']+'>|typing\.\w+\[.*\])\.?")
_ABSTRACT = re.compile(r"Expected an instantiatable class, but (?P<class_path>\S+ )?is abstract")
_NESTED = re.compile(r"NestedArg\(key='(?P<key>[^']*)', val=(?P<value>.*)\)")
_NAMES = {
    "<class 'int'>": "an integer (int)",
    "<class 'float'>": "a number (float)",
    "<class 'bool'>": "true or false",
    "<class 'str'>": "a string",
}


@contextlib.contextmanager
def full_messages(full: bool) -> Iterator[None]:
    """Within it, a refused argument prints the parser's usage and whole message (``full``)."""
    token = _FULL_MESSAGES.set(full)
    try:
        yield
    finally:
        _FULL_MESSAGES.reset(token)


class OneLineErrors:
    """A jsonargparse parser mixin whose refusals exit with one line, ``error: ...``, and
    status 2; a nested parser (``exit_on_error`` False) raises as before, for its caller."""

    exit_on_error: bool

    def error(self, message: str, ex: Exception | None = None) -> NoReturn:
        """Print ``message`` as one line and exit 2 (with ``--debug``, as jsonargparse does)."""
        if not self.exit_on_error or _FULL_MESSAGES.get():
            super().error(message, ex)  # type: ignore[misc]
        sys.stderr.write(f"error: {one_line(message)}\n")
        raise SystemExit(2)


@dataclass
class _Node:
    """A line of the parser's message and the lines indented under it."""

    text: str
    children: list[_Node] = field(default_factory=list)


def _tree(message: str) -> list[_Node]:
    """The message's lines as a tree by their indentation (a bullet's ``- `` dropped)."""
    root = _Node("")
    stack: list[tuple[int, _Node]] = [(-1, root)]
    for line in message.splitlines():
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        text = line.strip()
        if text.startswith("- "):
            text, indent = text[2:], indent + 2
        while stack[-1][0] >= indent:
            stack.pop()
        node = _Node(text)
        stack[-1][1].children.append(node)
        stack.append((indent, node))
    return root.children


def one_line(message: str) -> str:
    """The parser's ``message`` as one line naming the argument, the value given and what is
    valid (a type, the choices, a class that imports); another message, its lines joined."""
    explained = _explain(_tree(message), [])
    return explained or " ".join(line.strip() for line in message.splitlines() if line.strip())


def _explain(nodes: list[_Node], path: list[str], given: str | None = None) -> str | None:
    """What the message ``nodes`` under the argument ``path`` say was wrong, or None."""
    given = _given(nodes) or given
    for node in nodes:
        if match := _KEY.fullmatch(node.text) or _CLASS_PATH.fullmatch(node.text):
            nested = ([_Node(match["rest"])] if match["rest"] else []) + node.children
            if "key" in match.groupdict():
                return _explain(nested, path + match["key"].split("."), given)
            if any(_KEY.fullmatch(child.text) for child in nested):
                return _explain(nested, [*path, "init_args"], given)
            return _unimportable(path, match["class_path"], nested)
        if node.text.startswith("Does not validate against any of the Union subtypes"):
            errors = next((n.children for n in nodes if n.text == "Errors:"), [])
            chosen = [n for n in errors if not _OTHER_ALTERNATIVES.match(n.text)] or errors
            types = [_EXPECTED.fullmatch(n.text) for n in chosen]
            if len(chosen) > 1 and all(types) and not any(n.children for n in chosen):
                valid = _valid(*(match["type"] for match in types if match))
                return _wrong_type(path, valid, given or "", None)
            return _explain(chosen[:1], path, given) if chosen else None
        if match := _TYPE.fullmatch(node.text):
            return _wrong_type(path, _valid(match["type"]), match["value"], given)
        if match := _ABSTRACT.fullmatch(node.text):
            return _abstract(path, match["class_path"] or _class_path_of(given))
        if node.text.startswith(("Subtypes:", "Errors:", "Given value")):
            continue
        if _OTHER_ALTERNATIVES.match(node.text) and len(nodes) > 1:
            continue
        if (match := _EXPECTED.fullmatch(node.text)) and given is not None:
            return _wrong_type(path, _valid(match["type"]), given, None)
        if not path:
            return node.text  # a message of its own: "unrecognized arguments: --x 1"
        return f"{_name(path)} {given}: {node.text}" if given else f"{_name(path)}: {node.text}"
    return None


def _given(nodes: list[_Node]) -> str | None:
    """The value the message says was given (a nested argument's own), if it says so."""
    for node in nodes:
        if node.text.startswith("Given value:"):
            value = node.text.removeprefix("Given value:").strip()
            nested = _NESTED.fullmatch(value)
            return nested["value"].strip("'") if nested else value
    return None


def _name(path: list[str]) -> str:
    """The argument at ``path`` as a flag (``--data.init_args.seed_offset``)."""
    return "--" + ".".join(path) if path else "the arguments"


def _valid(*expected: str) -> str:
    """Types as the parser names them (``<class 'int'>``, ``typing.Literal[...]``) in words,
    the choices of every Literal among them as one list."""
    choices: list[str] = []
    others: list[str] = []
    for name in expected:
        literal = re.fullmatch(r"typing\.Literal\[(.*)\]", name)
        try:
            values = ast.literal_eval(f"[{literal[1]}]") if literal else None
        except (ValueError, SyntaxError):
            values = None
        if values is None:
            others.append(_NAMES.get(name, name))
        else:
            choices += [str(value) for value in values if str(value) not in choices]
    words = ([f"one of {', '.join(choices)}"] if choices else []) + others
    return " or ".join(words)


def _wrong_type(path: list[str], valid: str, value: str, given: str | None) -> str:
    """A value of the wrong type: the argument, the value given (and as read), what it takes."""
    shown = given or value
    read = f"read as {value}" if given and given != value else ""
    if valid == _NAMES["<class 'int'>"] and re.fullmatch(r"-?\d+\.0", value):
        read += (", " if read else "") + (
            f"a number with an exponent or a point is a float: write {int(float(value))}"
        )
    return f"{_name(path)}: expected {valid}, got {shown}" + (f" ({read})" if read else "")


def _unimportable(path: list[str], class_path: str, reason: list[_Node]) -> str:
    """A class_path the parser refused with no argument's key: an argument the class does not
    take, naming those it does; or a class that does not import, why, and an example."""
    why = " ".join(node.text for node in _flatten(reason)) or "it does not import"
    try:
        imported = import_object(class_path)
    except Exception:
        imported = None
    option = re.fullmatch(r"Option '(?P<key>[^']+)' is not accepted", why)
    if imported is not None and option:
        taken = _arguments_taken(imported)
        return (
            f"{_name([*path, 'init_args', option['key']])}: {class_path} takes no argument "
            f"{option['key']}; it takes {', '.join(taken) or 'none'}"
        )
    if imported is not None:
        return f"{_name([*path, 'class_path'])} {class_path}: {why}"
    return cannot_import(_name([*path, "class_path"]), class_path, why, path[-1] if path else "")


def cannot_import(flag: str, class_path: str, why: str, section: str) -> str:
    """A class path given to ``flag`` that does not import: why, and an example of ``section``'s."""
    example = EXAMPLES.get(section, "my_package.module.MyClass")
    return (
        f"{flag} {class_path} cannot be imported ({why}); give a class's import path, "
        f"e.g. {example}"
    )


def _arguments_taken(cls: Any) -> list[str]:
    """The keyword arguments a class takes: its ``__init__``'s and, via ``**kwargs``, its bases'."""
    taken: list[str] = []
    for base in cls.__mro__ if isinstance(cls, type) else ():
        if "__init__" not in vars(base):
            continue
        parameters = list(inspect.signature(vars(base)["__init__"]).parameters.values())[1:]
        taken += [
            p.name
            for p in parameters
            if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD) and p.name not in taken
        ]
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            break
    return taken


def _abstract(path: list[str], class_path: str | None) -> str:
    """An abstract class given: the methods it does not implement."""
    class_path = class_path.strip() if class_path else None
    try:
        missing = missing_methods(import_object(class_path)) if class_path else []
    except Exception as error:
        return f"{_name(path)} {class_path} cannot be imported ({import_failure(error)})"
    if not missing:
        return f"{_name(path)} {class_path}: the class is abstract; give one that can be built"
    return (
        f"{_name(path)} {class_path} cannot be built: it does not implement "
        f"{', '.join(missing)} (abstract in its base class; a SurpriseModel implements "
        "surprise, expected_frames and trajectories: docs/your_model.md)"
    )


def _class_path_of(given: str | None) -> str | None:
    """The class path of a given value: itself, or a mapping's ``class_path``."""
    if given is None:
        return None
    try:
        value: Any = ast.literal_eval(given)
    except (ValueError, SyntaxError):
        return given
    if isinstance(value, dict):
        return value.get("class_path")
    return str(value)


def _flatten(nodes: list[_Node]) -> Iterator[_Node]:
    """Every node of ``nodes`` and under them, in order."""
    for node in nodes:
        yield node
        yield from _flatten(node.children)

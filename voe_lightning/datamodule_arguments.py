"""Constructor argument checks shared by the DataModules: a bad value is refused when the
DataModule is built (``--data.init_args.x``), named with its valid range, not deep inside
``prepare_data`` or a DataLoader worker."""

from __future__ import annotations


def check_at_least(minimums: dict[str, tuple[object, int]]) -> None:
    """Raise a ValueError naming the first argument that is not an integer of at least its
    minimum; ``minimums`` maps a name to (value, minimum). None values are left to the caller."""
    for name, (value, minimum) in minimums.items():
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ValueError(f"{name} must be an integer of at least {minimum}, got {value!r}")


def check_fraction(name: str, value: object) -> None:
    """Raise a ValueError unless ``value`` is a number in [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= 1:
        raise ValueError(f"{name} must be a number in [0, 1], got {value!r}")

"""Reading typed fields out of plain dicts (parsed JSON), with one-line errors.

Every record's ``from_dict`` goes through these, so a file that parses but holds the wrong
type (a string where a 4x4 list belongs, a list where an object belongs) is refused with a
message naming the record, the field, what it got and what it expects.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from spacecal.core.errors import InvalidInputError
from spacecal.geometry.transforms import is_rigid_transform


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def get_mapping(data: Mapping[str, Any], key: str, what: str, default: Any = None) -> dict[str, Any]:
    """``data[key]`` as a dict (``default`` or ``{}`` when absent or null)."""
    value = data.get(key)
    if value is None:
        return {} if default is None else default
    if not isinstance(value, Mapping):
        raise InvalidInputError(f"{what}: {key!r} must be an object, got {_describe(value)}")
    return dict(value)


def get_number(data: Mapping[str, Any], key: str, what: str, default: float | None = None) -> float:
    """``data[key]`` as a finite float."""
    if key not in data or data[key] is None:
        if default is None:
            raise InvalidInputError(f"{what}: missing number {key!r}")
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise InvalidInputError(f"{what}: {key!r} must be a finite number, got {_describe(value)}")
    return float(value)


def get_str(data: Mapping[str, Any], key: str, what: str, default: str | None = None) -> str:
    """``data[key]`` as a string."""
    value = data.get(key, default)
    if not isinstance(value, str):
        raise InvalidInputError(f"{what}: {key!r} must be a string, got {_describe(value)}")
    return value


def as_array(value: Any, shape: tuple[int | None, ...], name: str, what: str) -> np.ndarray:
    """``value`` as a finite float array of ``shape`` (None = any length)."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what}: {name!r} must be numbers of shape {shape_text(shape)}") from None
    if not has_shape(array, shape):
        raise InvalidInputError(
            f"{what}: {name!r} must have shape {shape_text(shape)}, got {tuple(array.shape)}"
        )
    if not np.all(np.isfinite(array)):
        raise InvalidInputError(f"{what}: {name!r} holds NaN or infinite values")
    return array


def as_covariance(value: Any, size: int, name: str, what: str) -> np.ndarray:
    """``value`` as a covariance matrix (size, size): finite, symmetric, not negative."""
    covariance = as_array(value, (size, size), name, what)
    if (
        not np.allclose(covariance, covariance.T, atol=1e-9)
        or np.min(np.linalg.eigvalsh(covariance)) < -1e-12
    ):
        raise InvalidInputError(f"{what}: {name} is not a covariance (symmetric, not negative)")
    return covariance


def as_transform(value: Any, name: str, what: str) -> np.ndarray:
    """``value`` as a 4x4 rigid transform (rotation orthonormal, det +1, last row 0 0 0 1)."""
    try:
        matrix = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InvalidInputError(f"{what}: {name!r} is not a 4x4 rigid transform (not numbers)") from None
    if matrix.shape != (4, 4):
        raise InvalidInputError(f"{what}: {name!r} is not a 4x4 rigid transform: shape {matrix.shape}")
    matrix = as_array(matrix, (4, 4), name, what)
    if not is_rigid_transform(matrix, atol=1e-6):
        raise InvalidInputError(
            f"{what}: {name!r} is not a rigid transform (4x4 with a rotation and 0 0 0 1)"
        )
    return matrix


def as_transform_stack(value: Any, name: str, what: str) -> np.ndarray:
    """``value`` as (N, 4, 4) rigid transforms."""
    stack = as_array(value, (None, 4, 4), name, what)
    for index, matrix in enumerate(stack):
        if not is_rigid_transform(matrix, atol=1e-6):
            raise InvalidInputError(f"{what}: {name}[{index}] is not a rigid transform")
    return stack


def has_shape(array: np.ndarray, shape: tuple[int | None, ...]) -> bool:
    """Whether ``array`` has ``shape`` (None: any length along that axis)."""
    return array.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, array.shape))


def shape_text(shape: tuple[int | None, ...]) -> str:
    """``shape`` as a message shows it, an axis of any length as N."""
    return "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"


def check_schema(data: Mapping[str, Any], schema: str, versions: tuple[int, ...], what: str) -> int:
    """The file's schema version, after checking its ``schema`` name (when present) and version."""
    name = data.get("schema", schema)
    if name != schema:
        raise InvalidInputError(f"{what}: this is a {name!r} file, not {schema!r}")
    version = data.get("schema_version", versions[0])
    if isinstance(version, bool) or version not in versions:
        if isinstance(version, (int, float)) and not isinstance(version, bool) and version > max(versions):
            raise InvalidInputError(
                f"{what}: schema_version {_describe(version)} is newer than this spacecal reads "
                f"({', '.join(map(str, versions))}): written by a newer spacecal, update it to read this file"
            )
        raise InvalidInputError(
            f"{what}: schema_version {_describe(version)} is not supported "
            f"(this spacecal reads {', '.join(map(str, versions))})"
        )
    return int(version)


class ReadOnlyMapping(Mapping[str, Any]):
    """A mapping nothing can change after it is built (a record's content stays as built).

    Unlike :class:`types.MappingProxyType` it pickles and deep-copies: a calibration travels
    to and from the station's motion processes.
    """

    __slots__ = ("_items",)
    _items: dict[str, Any]

    def __init__(self, items: Mapping[str, Any] | None = None):
        object.__setattr__(self, "_items", dict(items or {}))

    def __getitem__(self, key: str) -> Any:
        return self._items[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __setattr__(self, name: str, value: Any) -> None:
        raise AttributeError(f"{type(self).__name__} cannot be changed")

    def __reduce__(self) -> tuple[Any, ...]:
        return (type(self), (self._items,))

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self._items!r})"


def plain(value: Any) -> Any:
    """Numpy values inside nested containers -> JSON-ready Python values."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value

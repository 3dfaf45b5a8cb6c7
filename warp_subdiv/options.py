"""Refinement options: one frozen, validated :class:`Options` object, built once from the public keywords.

Every front end (``refine``, ``Refiner``, the USD bake, ``render --levels``, the CLI, face-varying channels)
builds its refiner from an :class:`Options`, so they cannot drift apart. Closed sets are string enums: a
member compares equal to its value (``Scheme.LOOP == "loop"``), and the constructor accepts the value in any
letter case (and the USD / OpenSubdiv spellings of the scheme), so ``scheme="LOOP"`` and
``rules="OpenSubdiv"`` are treated alike.
"""
from __future__ import annotations

import dataclasses
import difflib
import enum
import math
import numbers
import sys

import numpy as np

from .checks import NOT_NUMBERS, first_non_number
from .errors import SubdivInputError


class Choice(str, enum.Enum):
    """A closed set of string values; ``str()`` and ``format()`` give the value."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)

    @classmethod
    def parse(cls, value, option: str, label: str | None = None):
        """The member named by ``value`` (a member, or its value in any letter case, or an alias).

        ``option`` is the keyword at fault (the error's ``option`` field), ``label`` its name in the message."""
        if isinstance(value, cls):
            return value
        if isinstance(value, str):
            key = value.strip().lower()
            for member in cls:
                if key == member.value:
                    return member
            alias = cls._aliases().get(key)
            if alias is not None:
                return cls(alias)
        raise SubdivInputError(
            f"{label or option} must be one of {', '.join(repr(m.value) for m in cls)}, got {value!r}",
            option=option, value=value,
        )

    @classmethod
    def _aliases(cls) -> dict:
        return {}

    @classmethod
    def values(cls) -> tuple:
        """Every member's value, in declaration order (the values an option of this kind accepts)."""
        return tuple(m.value for m in cls)


class Scheme(Choice):
    """The subdivision scheme."""

    CATMULL_CLARK = "catmull-clark"
    LOOP = "loop"

    @classmethod
    def _aliases(cls) -> dict:  # USD's catmullClark, OpenSubdiv's SCHEME_CATMARK
        return {"catmullclark": "catmull-clark", "catmark": "catmull-clark", "catmull_clark": "catmull-clark"}


class RuleSet(Choice):
    """The paper's rules (Biermann, Levin, Zorin 2000) or OpenSubdiv's uniform refinement."""

    PIECEWISE_SMOOTH = "piecewise-smooth"
    OPENSUBDIV = "opensubdiv"


class Boundary(Choice):
    """OpenSubdiv's VtxBoundaryInterpolation."""

    EDGE_AND_CORNER = "edge-and-corner"
    EDGE_ONLY = "edge-only"
    NONE = "none"


class Precision(Choice):
    """Evaluation precision (weights are always computed in float64)."""

    FLOAT32 = "float32"
    FLOAT64 = "float64"


class LoopBeta(Choice):
    """Loop's interior ring weight: Loop's original beta, or Warren's 3/(8k) (the paper's choice)."""

    LOOP = "loop"
    WARREN = "warren"


class CreaseMethod(Choice):
    """How semi-sharp creases decay per level (OpenSubdiv's CreasingMethod)."""

    UNIFORM = "uniform"
    CHAIKIN = "chaikin"


class TriangleSubdivision(Choice):
    """Catmull-Clark edge weights next to triangles (OpenSubdiv's TriangleSubdivision)."""

    CATMARK = "catmark"
    SMOOTH = "smooth"


class FaceVaryingMode(Choice):
    """OpenSubdiv's FVarLinearInterpolation for face-varying channels."""

    NONE = "none"
    CORNERS_ONLY = "corners-only"
    CORNERS_PLUS1 = "corners-plus1"
    CORNERS_PLUS2 = "corners-plus2"
    BOUNDARIES = "boundaries"
    ALL = "all"


_KW_ONLY = {"kw_only": True} if sys.version_info >= (3, 10) else {}


@dataclasses.dataclass(frozen=True, eq=False, **_KW_ONLY)
class Options:
    """What determines a refinement's result (the device and the memory limit do not).

    Values are validated and normalised on construction; an invalid value raises :class:`SubdivInputError`
    with ``option`` and ``value`` set. See :func:`warp_subdiv.refine` for the meaning of each option.
    ``linear`` is bilinear refinement (every vertex a corner, every edge sharp), used for face-varying data in
    mode "all" and USD's bilinear scheme.
    """

    scheme: Scheme = Scheme.CATMULL_CLARK
    rules: RuleSet = RuleSet.PIECEWISE_SMOOTH
    boundary: Boundary = Boundary.EDGE_AND_CORNER
    precision: Precision = Precision.FLOAT32
    loop_beta: LoopBeta = LoopBeta.LOOP
    triangulate: bool = True
    flatness: object = None
    normal_strength: float = 1.0
    crease_method: CreaseMethod = CreaseMethod.UNIFORM
    triangle_subdivision: TriangleSubdivision = TriangleSubdivision.CATMARK
    linear: bool = False

    def __post_init__(self):
        def put(name, value):
            object.__setattr__(self, name, value)

        for name, kind in (("scheme", Scheme), ("rules", RuleSet), ("boundary", Boundary), ("precision", Precision),
                           ("loop_beta", LoopBeta), ("crease_method", CreaseMethod),
                           ("triangle_subdivision", TriangleSubdivision)):
            put(name, kind.parse(getattr(self, name), name))
        for name in ("triangulate", "linear"):
            value = getattr(self, name)
            if not isinstance(value, (bool, np.bool_)):
                raise SubdivInputError(f"{name} must be True or False, got {value!r}", option=name, value=value)
            put(name, bool(value))
        put("normal_strength", _unit_number(self.normal_strength, "normal_strength"))
        put("flatness", _flatness(self.flatness))
        paper = self.rules == RuleSet.PIECEWISE_SMOOTH
        if not paper and self.flatness is not None:
            raise SubdivInputError("flatness is a piecewise-smooth rule; rules='opensubdiv' has none",
                                   option="flatness", value=self.flatness)
        default_strength = _OPTION_FIELDS["normal_strength"].default
        if not paper and self.normal_strength != default_strength:
            raise SubdivInputError(f"normal_strength={self.normal_strength:g} is a piecewise-smooth rule (normal "
                                   "control); rules='opensubdiv' has none (leave normal_strength at its default "
                                   f"{default_strength:g})", option="normal_strength", value=self.normal_strength)
        if not paper and self.loop_beta != LoopBeta.LOOP:
            raise SubdivInputError(f"loop_beta={self.loop_beta.value!r} is a piecewise-smooth rule; "
                                   "rules='opensubdiv' uses Loop's original beta only",
                                   option="loop_beta", value=self.loop_beta.value)

    @property
    def piecewise_smooth(self) -> bool:
        """Whether the paper's rules (and so its projections) apply."""
        return self.rules == RuleSet.PIECEWISE_SMOOTH

    @property
    def smooth_triangles(self) -> bool:
        """OpenSubdiv's TRI_SUB_SMOOTH applies (Catmull-Clark only)."""
        return self.triangle_subdivision == TriangleSubdivision.SMOOTH and self.scheme == Scheme.CATMULL_CLARK

    def replace(self, **changes) -> "Options":
        """A copy with ``changes`` applied (validated again)."""
        return dataclasses.replace(self, **changes)

    @classmethod
    def given(cls, options: "Options | None", option_keywords: dict, caller: str | None = None) -> "Options":
        """The options of a call that takes either ``options=`` or option keywords (Refiner, LimitSurface,
        MeshBatch): ``options`` as given, else ``Options(**option_keywords)``; both at once is a TypeError.

        ``caller`` names that call in the errors: a keyword that is no option arrives here among the option
        keywords, so the TypeError says which call does not take it (and lists the options); an ``options``
        that is not an :class:`Options` (a dict, a string) is a TypeError too, before it fails deep inside."""
        if options is not None and not isinstance(options, cls):
            raise TypeError(f"options must be a warp_subdiv.Options, got {type(options).__name__} {options!r}: "
                            "build one (for a dict d, Options(**d)) or pass the options as keywords")
        unknown = [name for name in option_keywords if name not in _OPTION_FIELDS]
        if unknown:
            raise TypeError(_unknown_keywords_message(unknown, caller))
        if options is None:
            return cls(**option_keywords)
        if option_keywords:
            raise TypeError(f"pass either options= or option keywords, not both ({', '.join(option_keywords)})")
        return options

    def check_prescribed_normals(self, count: int) -> None:
        """Refuse ``count`` > 0 prescribed normals under rules other than the paper's (OpenSubdiv has no
        normal control)."""
        if not self.piecewise_smooth and count:
            raise SubdivInputError("prescribed normals need rules='piecewise-smooth' (OpenSubdiv has no normal "
                                   "control)", option="rules", element="normal")

    def as_dict(self) -> dict:
        """Plain Python values (strings for the closed sets, a list for a per-vertex flatness), for metadata."""
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, Choice):
                value = value.value
            elif isinstance(value, np.ndarray):
                value = [None if math.isnan(x) else float(x) for x in value]
            out[f.name] = value
        return out

    def __eq__(self, other) -> bool:
        if not isinstance(other, Options):
            return NotImplemented
        return self.as_dict() == other.as_dict()

    def __hash__(self) -> int:
        return hash(repr(sorted(self.as_dict().items())))


_OPTION_FIELDS = {f.name: f for f in dataclasses.fields(Options)}


def _unknown_keywords_message(unknown: list, caller: str | None) -> str:
    """Which keywords are no option, the option each was probably meant to be, and the options there are."""
    names = ", ".join(repr(name) for name in unknown)
    if caller:
        said = f"{caller} does not take {names}"
    else:
        said = f"{names} {'is' if len(unknown) == 1 else 'are'} not an option"
    guesses = []
    for name in unknown:
        close = difflib.get_close_matches(name, list(_OPTION_FIELDS), n=1)
        if close:
            guesses.append(f"did you mean {close[0]!r}" + (f" for {name!r}" if len(unknown) > 1 else ""))
    guess = f" ({'; '.join(guesses)})" if guesses else ""
    return f"{said}{guess}; the options are: {', '.join(_OPTION_FIELDS)}"


def _unit_number(value, option: str) -> float:
    """A finite number in [0, 1]."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise SubdivInputError(f"{option} must be a number in [0, 1], got {value!r}", option=option, value=value)
    number = float(value)
    if not 0.0 <= number <= 1.0:  # NaN fails too
        raise SubdivInputError(f"{option} {number} is outside [0, 1]", option=option, value=value)
    return number


def _refuse_flatness_items_that_are_not_numbers(value) -> None:
    """Refuse a per-vertex flatness holding a bool or a string (a numpy array of bools, strings or complex
    numbers, or a list with one among numbers), which numpy would convert to floats without a word."""
    if isinstance(value, np.ndarray) and value.dtype.kind in "bUSc":
        raise SubdivInputError(f"flatness must hold numbers (one per control vertex), got an array of "
                               f"{value.dtype} {value!r}", option="flatness", value=value)
    found = first_non_number(value)
    if found is None:
        return
    index, item = found
    raise SubdivInputError(f"flatness must hold numbers (one per control vertex), got {item!r} at vertex {index} "
                           "(a bool, a string or a complex number is not a flatness)", option="flatness",
                           element="vertex", index=index, value=item)


def _flatness(value):
    """None, a number in [0, 1], or a read-only float64 array of per-vertex values in [0, 1] or NaN (optimal)."""
    if value is None:
        return None
    if isinstance(value, NOT_NUMBERS):
        raise SubdivInputError(f"flatness must be None, a number in [0, 1] or one number per control vertex, got "
                               f"{value!r} (a bool, a string or a complex number is not a flatness)",
                               option="flatness", value=value)
    if isinstance(value, numbers.Real):
        return _unit_number(value, "flatness")
    _refuse_flatness_items_that_are_not_numbers(value)
    try:
        array = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SubdivInputError(f"flatness must be None, a number or one number per control vertex, got {value!r}",
                               option="flatness", value=value) from None
    if array.ndim == 0:
        return _unit_number(float(array), "flatness")
    if array.ndim != 1:
        raise SubdivInputError(f"flatness must be a number or a 1-D array (one value per control vertex), got "
                               f"shape {array.shape}", option="flatness", value=value)
    bad = np.flatnonzero(~np.isnan(array) & ~((array >= 0.0) & (array <= 1.0)))
    if len(bad):
        raise SubdivInputError(f"flatness {float(array[bad[0]])} at vertex {int(bad[0])} is outside [0, 1] (NaN: "
                               "the optimal s*)", option="flatness", element="vertex",
                               index=int(bad[0]), value=float(array[bad[0]]))
    array.flags.writeable = False
    return array

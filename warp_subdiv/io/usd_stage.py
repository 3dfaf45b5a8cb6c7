"""Opening a USD stage and choosing what of it to read: the stage itself (:func:`open_stage`, USD's errors in
one line by :func:`tf_message`), the prims a run is limited to (:func:`check_roots`) and the time samples a
``--frames`` range selects (:func:`parse_frames`, :func:`times_for_frames`).
"""
from __future__ import annotations

import math
import re

from pxr import Sdf, Tf, Usd

from ..errors import SubdivInputError

#: The time code of an attribute's default value (the one it holds apart from its time samples).
DEFAULT = Usd.TimeCode.Default()


def tf_message(exc: BaseException) -> str:
    """The useful part of a (multi-line) USD error: the first quoted message, without C++ namespaces."""
    text = str(exc)
    msgs = re.findall(r" : '(.*?)'(?:\n|$)", text, re.S)
    msg = msgs[0] if msgs else text.strip()
    msg = re.sub(r"pxrInternal_v\d+_\d+__pxrReserved__::", "", msg)
    return " ".join(msg.split())


def open_stage(path: str) -> Usd.Stage:
    """Open a USD file with everything loaded; SubdivInputError with one line when it cannot be read."""
    try:
        stage = Usd.Stage.Open(path, Usd.Stage.LoadAll)
    except Tf.ErrorException as exc:
        raise SubdivInputError(f"{path}: cannot open as USD: {tf_message(exc)}") from None
    if stage is None:
        raise SubdivInputError(f"{path}: cannot open as USD")
    return stage


def parse_frames(text: str | None):
    """'A:B', 'A:', ':B' or 'A' -> (start, end) with None for an open end; None -> None (all samples)."""
    if text is None:
        return None
    parts = str(text).split(":")
    try:
        if len(parts) == 1:
            a = b = float(parts[0])
        elif len(parts) == 2:
            a = float(parts[0]) if parts[0].strip() else None
            b = float(parts[1]) if parts[1].strip() else None
        else:
            raise ValueError
    except ValueError:
        raise SubdivInputError(f"frames {text!r}: give A:B, A:, :B or A (time codes)", option="frames",
                               value=text) from None
    if any(v is not None and not math.isfinite(v) for v in (a, b)):
        raise SubdivInputError(f"frames {text!r}: time codes must be finite numbers", option="frames", value=text)
    if a is not None and b is not None and a > b:
        raise SubdivInputError(f"frames {text!r}: the start is after the end", option="frames", value=text)
    return a, b


def in_frames(t, frames) -> bool:
    """Whether time ``t`` lies in the range ``frames`` ((start, end), None for an open end)."""
    a, b = frames
    return (a is None or t >= a) and (b is None or t <= b)


def times_for_frames(times, frames) -> list:
    """The times at which an attribute with time samples ``times`` is evaluated for ``frames`` (all its samples
    when None): its samples in [A, B], and A (B) where a sample lies before A (after B), so that the value USD
    holds or interpolates at the ends of the range from samples outside it is written too. Between those
    times the output has the input's own samples, and refinement is linear: every time in [A, B] reads as in
    the input. Non-empty whenever ``times`` is."""
    times = sorted(float(t) for t in times)
    if frames is None or not times:
        return times
    a, b = frames
    out = [t for t in times if in_frames(t, frames)]
    if a is not None and a not in out and times[0] < a:
        out.insert(0, float(a))
    if b is not None and b not in out and times[-1] > b:
        out.append(float(b))
    return out


def format_frames(frames) -> str:
    """(start, end) as the ``A:B`` text :func:`parse_frames` reads."""
    a, b = frames
    return f"{'' if a is None else f'{a:g}'}:{'' if b is None else f'{b:g}'}"


def check_roots(stage: Usd.Stage, prim_paths, where: str = "") -> list:
    """The prims named by ``prim_paths`` (absolute paths of active, defined, concrete prims; inside instances
    too), as Sdf paths; [] for none given. SubdivInputError naming the path otherwise."""
    roots = []
    for p in prim_paths or ():
        if not Sdf.Path.IsValidPathString(p) or not Sdf.Path(p).IsAbsolutePath():
            raise SubdivInputError(f"prims {p!r}: not an absolute prim path such as /World/Mesh", option="prims",
                                   value=p)
        prim = stage.GetPrimAtPath(p)
        if not prim or not prim.IsValid():
            raise SubdivInputError(f"{where}: {_missing(stage, p)}")
        _check_traversable(prim, where)
        roots.append(prim.GetPath())
    return roots


def _missing(stage: Usd.Stage, path: str) -> str:
    """Why there is no prim at ``path``: below an inactive prim (whose children are not composed), or none."""
    anc = Sdf.Path(path).GetParentPath()
    while anc != Sdf.Path.absoluteRootPath and not anc.isEmpty:
        prim = stage.GetPrimAtPath(anc)
        if prim and prim.IsValid():
            if not prim.IsActive():
                return f"{path} is under the inactive prim {anc} (active = false)"
            break
        anc = anc.GetParentPath()
    return f"no prim at {path}"


def _check_traversable(prim: Usd.Prim, where: str) -> None:
    """A prim picked by path must be part of the scene: active, not abstract (a class or under one), defined."""
    path = prim.GetPath()
    if not prim.IsActive():
        raise SubdivInputError(f"{where}: {path} is inactive (active = false)")
    if prim.IsAbstract():
        cls = prim
        while cls and cls.GetSpecifier() != Sdf.SpecifierClass:
            cls = cls.GetParent()
        what = "a class" if cls == prim else f"under the class {cls.GetPath()}"
        raise SubdivInputError(f"{where}: {path} is abstract ({what}), not part of the scene")
    if not prim.IsDefined():
        raise SubdivInputError(f"{where}: {path} is not defined (only an over), not part of the scene")


__all__ = ["DEFAULT", "check_roots", "format_frames", "in_frames", "open_stage", "parse_frames", "tf_message",
           "times_for_frames"]

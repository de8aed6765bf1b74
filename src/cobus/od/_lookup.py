"""Names as people type them: case and separators do not matter, near misses get suggestions.

EDS names are written as the vendor wrote them (``"Producer Heartbeat Time"``,
``"Producer heartbeat time"``, ``"Producer_heartbeat_time"``); a user should not have to
guess which. :func:`match_name` finds the one meant, :func:`did_you_mean` says what is close.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable

from cobus.od._model import Array, Object, ObjectDictionary, ObjectDictionaryError, Record, Variable

__all__ = [
    "NameLookupError",
    "did_you_mean",
    "match_key",
    "match_name",
    "normalize_name",
    "parse_address",
    "resolve",
    "resolve_object",
    "suggestions",
]

_SEPARATORS = re.compile(r"[\s_\-]+")


def normalize_name(name: str) -> str:
    """``name`` in lower case with runs of blanks, ``_`` and ``-`` as one space."""
    return _SEPARATORS.sub(" ", name).strip().casefold()


def match_name(key: str, names: Iterable[str]) -> str | None:
    """The one name of ``names`` that ``key`` means: itself, else the only name equal to it
    but for case and separators; None when there is none or more than one."""
    candidates = list(names)
    if key in candidates:
        return key
    wanted = normalize_name(key)
    found = [n for n in candidates if normalize_name(n) == wanted]
    return found[0] if len(set(found)) == 1 else None


def did_you_mean(key: str, names: Iterable[str]) -> str:
    """``" (did you mean 'A' or 'B'?)"`` for the names close to ``key``, else ``""``."""
    by_norm: dict[str, str] = {}
    for name in names:
        by_norm.setdefault(normalize_name(name), name)
    close = difflib.get_close_matches(normalize_name(key), list(by_norm), n=3, cutoff=0.6)
    if not close:
        return ""
    quoted = [repr(by_norm[c]) for c in close]
    listing = quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"
    return f" (did you mean {listing}?)"


# ------------------------------------------------------------------ the one name resolver

#: An address as people write it: ``0x1018``, ``1018h``, ``0x1018:01``, ``1018h sub 1``,
#: ``6041sub0`` (the sub-index in hex, as EDS files and manuals write it).
_ADDRESS = re.compile(
    r"\s*(0x)?([0-9a-f]{1,4})(h)?\s*(?:(?::|sub)\s*(?:0x)?([0-9a-f]{1,2})h?)?\s*\Z", re.I
)
# (bounded digits: a sub-index of 5,000 digits is no sub-index, not a crash)
_SUB_NUMBER = re.compile(r"(.*?)\[\s*(0x[0-9a-fA-F]{1,8}|[0-9]{1,10})\s*\]\s*\Z")
#: Keys longer than this get no suggestions (a close-match search grows with the product of
#: the lengths).
_SUGGEST_LENGTH = 100


def match_key(name: str) -> str:
    """The form two names are compared in: case folded, every run of characters that are
    not letters or digits one space (``"Vendor-ID"``, ``"vendor id"`` and ``"VENDOR_ID"``
    are one name)."""
    return _NOT_WORD.sub(" ", name.casefold()).strip()


_NOT_WORD = re.compile(r"[\W_]+")


def parse_address(text: str) -> tuple[int, int | None] | None:
    """``(index, sub-index or None)`` for an address written as text (``"0x1018:01"``,
    ``"1018h sub 1"``, ``"0x6041"``, ``"6041h"``); None for text that is no address: a bare
    number without ``0x`` or a sub-index, or fewer than four digits before an ``h`` ("Each",
    "Dach" are names)."""
    match = _ADDRESS.match(text)
    if match is None:
        return None
    prefix, digits, suffix, sub = match.groups()
    if not (prefix or sub is not None or (suffix and len(digits) == 4)):
        return None
    return int(digits, 16), None if sub is None else int(sub, 16)


def _number(text: str) -> int:
    """A sub-index written as text: ``0x..`` hexadecimal, else decimal (``"01"`` is 1)."""
    return int(text, 16) if text[:2].lower() == "0x" else int(text, 10)


class _Names:
    """The name tables of one dictionary, by :func:`match_key` (built when first needed,
    again when the dictionary grew)."""

    def __init__(self, od: ObjectDictionary) -> None:
        self.stamp = _stamp(od)
        self.objects: dict[str, list[Object]] = {}
        #: A sub-object by its own name alone, where no object has that name.
        self.subs: dict[str, list[Variable]] = {}
        #: "Record.Sub" names as the EDS writes them, for suggestions.
        self.shown: dict[str, str] = {}
        for obj in od:
            if obj.index < 0x1000:  # (the data type definitions have type names)
                continue
            key = match_key(obj.name)
            self.objects.setdefault(key, []).append(obj)
            self.shown.setdefault(key, obj.name)
            if isinstance(obj, Variable):
                continue
            for var in obj:
                sub = match_key(var.name)
                self.shown.setdefault(f"{key} . {sub}", f"{obj.name}.{var.name}")
                if var.subindex:
                    self.subs.setdefault(sub, []).append(var)


def _stamp(od: ObjectDictionary) -> tuple[int, int]:
    """What the tables follow: objects added or removed, sub-objects added to a record."""
    return od._version, sum(len(getattr(obj, "subindices", ())) for obj in od._objects.values())


def _names(od: ObjectDictionary) -> _Names:
    tables = od._name_tables
    if not isinstance(tables, _Names) or tables.stamp != _stamp(od):
        tables = od._name_tables = _Names(od)
    return tables


def suggestions(od: ObjectDictionary, key: str) -> list[str]:
    """Up to three names of ``od`` close to ``key`` ("Record.Sub" for sub-objects), as the
    EDS writes them."""
    if len(key) > _SUGGEST_LENGTH:
        return []
    shown = _names(od).shown
    close = difflib.get_close_matches(match_key(key), list(shown), n=3, cutoff=0.6)
    return [shown[c] for c in close]


def _listing(names: list[str]) -> str:
    quoted = [repr(n) for n in names]
    if not quoted:
        return ""
    listing = quoted[0] if len(quoted) == 1 else f"{', '.join(quoted[:-1])} or {quoted[-1]}"
    return f" (did you mean {listing}?)"


def _unknown(od: ObjectDictionary, key: str, suggest: bool) -> NameLookupError:
    close = suggestions(od, key) if suggest else []
    return NameLookupError(f"no object named {key!r}{_listing(close)}", key=key, suggestions=close)


def resolve_object(od: ObjectDictionary, key: int | str, *, suggest: bool = True) -> Object:
    """The object ``key`` names: an index, its exact EDS name, an address as text
    (``"0x1018"``, ``"1018h"``), or a name with case and separators ignored.
    :class:`NameLookupError` says why none (with the close names unless ``suggest`` is
    False), or which several."""
    if isinstance(key, int) and not isinstance(key, bool):
        obj = od.get(key)
        if obj is None:
            raise NameLookupError(f"no object 0x{key:04X}", key=key)
        return obj
    if not isinstance(key, str):
        raise NameLookupError(
            f"{key!r} is no object name or index: give a name from the EDS, an index, or an "
            'address such as "0x1018:01"',
            key=key,
        )
    obj = od.get(key)  # the exact name first: it is what the EDS says
    if obj is not None:
        return obj
    address = parse_address(key)
    if address is not None:
        if address[1] is not None:
            raise NameLookupError(f"{key!r} names a sub-object, not an object", key=key)
        return resolve_object(od, address[0])
    found = _names(od).objects.get(match_key(key), [])
    if len(found) == 1:
        return found[0]
    if found:
        where = ", ".join(f"0x{o.index:04X}" for o in found)
        raise NameLookupError(
            f"{key!r} names several objects ({where}): use the index", key=key, candidates=found
        )
    raise _unknown(od, key, suggest)


def resolve(
    od: ObjectDictionary,
    key: int | str | tuple[int | str, int | str],
    subindex: int | str | None = None,
    *,
    suggest: bool = True,
) -> Variable:
    """The variable ``key`` (and ``subindex``) name, in every form people write:

    - ``0x1018, 1`` / ``(0x1018, 1)`` / ``"0x1018:01"`` / ``"1018h sub 1"`` — addresses;
    - ``"Producer heartbeat time"`` — a name, case and separators ignored (the exact EDS
      name first, whatever it looks like);
    - ``"Identity object", "Vendor-ID"`` / ``"Identity object.Vendor-ID"`` /
      ``"Identity object[1]"`` — a sub-object of a record or array;
    - ``"Vendor-ID"`` alone — a sub-object by its own name, where only one has it.

    A record or array named without a sub-index is its sub-index 0. :class:`NameLookupError`
    (a ``KeyError``) says why nothing matches, with the close names unless ``suggest`` is
    False, or which several objects a name matches.
    """
    if isinstance(key, tuple):
        if subindex is not None or len(key) != 2:
            raise NameLookupError(f"{key!r}: give (index, sub-index) once", key=key)
        key, subindex = key
    if isinstance(key, str) and subindex is None:
        exact = od.get(key)
        if exact is not None:
            return _sub(exact, 0)
        address = parse_address(key)
        if address is not None:
            key, subindex = address
        else:
            split = _split(od, key)
            if split is not None:
                return split
    try:
        obj = resolve_object(od, key, suggest=False)
    except NameLookupError as exc:
        if not isinstance(key, str) or exc.candidates or parse_address(key) is not None:
            raise
        if subindex is None:
            subs = _names(od).subs.get(match_key(key), [])
            if len(subs) == 1:
                return subs[0]
        raise _unknown(od, key, suggest) from None
    return _sub(obj, 0 if subindex is None else subindex)


def _split(od: ObjectDictionary, text: str) -> Variable | None:
    """The sub-object ``"Record[n]"`` or ``"Record.Sub"`` names, when the whole text names
    no object (None: it is no such form)."""
    if _names(od).objects.get(match_key(text)):
        return None  # (a name of an object, case or separators aside)
    match = _SUB_NUMBER.match(text)
    if match is not None and match.group(1).strip():
        try:
            obj = resolve_object(od, match.group(1), suggest=False)
        except NameLookupError:
            obj = None
        if obj is not None:
            return _sub(obj, _number(match.group(2)))
    if "." not in text:
        return None
    for cut in [i for i, c in enumerate(text) if c == "."]:
        try:
            obj = resolve_object(od, text[:cut], suggest=False)
        except NameLookupError:
            continue
        if not isinstance(obj, Variable):
            return _sub(obj, text[cut + 1 :])
    return None


def _sub(obj: Object, subindex: int | str) -> Variable:
    where = f"0x{obj.index:04X} ({obj.name!r})"
    if isinstance(obj, Variable):
        if subindex == 0 or (
            isinstance(subindex, str)
            and (
                subindex.strip() in ("0", "0x0", "0x00")
                or match_key(subindex) == match_key(obj.name)
            )
        ):
            return obj
        shown = subindex if isinstance(subindex, int) else repr(subindex)
        raise NameLookupError(
            f"{where} is a single variable; it has no sub-index {shown}", key=subindex, found=obj
        )
    if isinstance(subindex, str):
        named = _one_of(obj, subindex, [v for v in obj if v.name == subindex])  # exact first
        if named is not None:
            return named
        number = _SUB_TEXT.match(subindex)
        if number is not None:
            subindex = _number(number.group(1))
    if isinstance(subindex, int) and not isinstance(subindex, bool):
        var = obj.get(subindex)
        if var is None:
            subs = ", ".join(str(v.subindex) for v in obj)
            raise NameLookupError(
                f"{where} has no sub-index {subindex} (it has {subs})", key=subindex, found=obj
            )
        return var
    if not isinstance(subindex, str):
        raise NameLookupError(
            f"{subindex!r} is no sub-index or sub-object name", key=subindex, found=obj
        )
    wanted = match_key(subindex)
    found = _one_of(obj, subindex, [v for v in obj if match_key(v.name) == wanted])
    if found is not None:
        return found
    names = [v.name for v in obj]
    close = difflib.get_close_matches(wanted, [match_key(n) for n in names], n=3, cutoff=0.6)
    near = [n for n in names if match_key(n) in close][:3]
    raise NameLookupError(
        f"{where} has no sub-object {subindex!r}{_listing(near)}",
        key=subindex,
        suggestions=near,
        found=obj,
    )


def _one_of(obj: Record | Array, name: str, found: list[Variable]) -> Variable | None:
    """The one sub-object of ``obj`` that ``name`` matched (None: none did)."""
    if len(found) < 2:
        return found[0] if found else None
    subs = ", ".join(str(v.subindex) for v in found)
    raise NameLookupError(
        f"0x{obj.index:04X} ({obj.name!r}): {name!r} names sub-indices {subs}; use the sub-index",
        key=name,
        candidates=found,
        found=obj,
    )


_SUB_TEXT = re.compile(r"\s*(0x[0-9a-fA-F]{1,2}|[0-9]{1,3})\s*\Z")


class NameLookupError(ObjectDictionaryError):
    """A key names no object of the dictionary (``suggestions``: the close names, as the EDS
    writes them) or several (``candidates``); ``found`` is the object when only its
    sub-index is what matches nothing (CiA 301: 06090011h, not 06020000h)."""

    def __init__(
        self,
        message: str,
        *,
        key: object,
        suggestions: list[str] | tuple[str, ...] = (),
        candidates: list[Object] | list[Variable] | tuple[Object, ...] = (),
        found: Object | None = None,
    ) -> None:
        super().__init__(message)
        self.key = key
        self.found = found
        self.suggestions = list(suggestions)
        self.candidates = list(candidates)

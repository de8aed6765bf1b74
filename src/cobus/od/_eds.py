"""Reading CiA 306 EDS and DCF files into an :class:`ObjectDictionary`.

The reader is tolerant by default: it loads what real files contain and records every
deviation as a :class:`Finding` (``od.findings``) with its line. ``strict=True`` raises an
:class:`EdsError` at the first error instead. Warnings never stop loading.

It reads in two passes: a tokenizer that splits the text into sections of ``key=value``
(remembering lines only for sections, so the common path allocates nothing per key), then a
builder that turns the sections into objects. Section and key names are case-insensitive.
Whole-line ``;`` and ``#`` comments are kept with the section they are in and the key they
follow (``od.file_comments``), to be written back.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

from cobus.errors import clip
from cobus.od._checks import check_dictionary
from cobus.od._errors import EdsError, Finding, Severity
from cobus.od._model import (
    REL_DEFAULT,
    REL_HIGH,
    REL_LOW,
    REL_PARAM,
    Access,
    Array,
    Commissioning,
    DeviceInfo,
    FileInfo,
    ObjectDictionary,
    ObjectType,
    Record,
    Variable,
    dummy_variable,
)
from cobus.od._types import INT_INFO, DataType
from cobus.od._values import TextError, parse_int, parse_value

__all__ = ["load", "loads"]

_OBJ_KEYS = (
    "ParameterName",
    "ObjectType",
    "DataType",
    "AccessType",
    "DefaultValue",
    "PDOMapping",
    "LowLimit",
    "HighLimit",
    "ParameterValue",
    "SubNumber",
    "CompactSubObj",
    "ObjFlags",
    "Denotation",
    "Description",
    "Unit",
    "Factor",
)
_OBJ_KEY_SET = frozenset(_OBJ_KEYS)
_OBJ_KEY_BY_LOWER = {k.lower(): k for k in _OBJ_KEYS}
_OPTIONAL_KEYS = frozenset(("Denotation", "Description", "Unit", "Factor", "ObjFlags"))
# Keys that only mean something on a VAR (or on a compact array/record).
_VAR_ONLY = (
    "DataType",
    "AccessType",
    "DefaultValue",
    "PDOMapping",
    "LowLimit",
    "HighLimit",
    "ParameterValue",
    "Unit",
    "Factor",
)

_OBJ_SECTION = re.compile(r"([0-9A-F]{4})(?:SUB([0-9A-F]+)|(NAME|VALUE|DENOTATION))?\Z")
_DUMMY_KEY = re.compile(r"DUMMY([0-9A-F]{4})\Z")
_BAUD_KEY = re.compile(r"BAUDRATE_(\d{1,7})\Z")
_LINE_KEY = re.compile(r"LINE(\d{1,4})\Z")  # up to Line9999: a comment, not a book

_ACCESS = {a.value: a for a in Access}
_DT_CACHE: dict[str, DataType] = {}
_OT_CACHE: dict[str, ObjectType] = {}
_BOOL_CACHE: dict[str, bool] = {"0": False, "1": True, "0x0": False, "0x1": True}

_FILE_INFO_KEYS = {
    "filename": "file_name",
    "fileversion": "file_version",
    "filerevision": "file_revision",
    "edsversion": "eds_version",
    "description": "description",
    "creationtime": "creation_time",
    "creationdate": "creation_date",
    "createdby": "created_by",
    "modificationtime": "modification_time",
    "modificationdate": "modification_date",
    "modifiedby": "modified_by",
    "lasteds": "last_eds",
}
# [DeviceInfo] keys: lower-case key -> (field, kind).
_DEVICE_INFO_KEYS = {
    "vendorname": ("vendor_name", str),
    "vendornumber": ("vendor_number", int),
    "productname": ("product_name", str),
    "productnumber": ("product_number", int),
    "revisionnumber": ("revision_number", int),
    "ordercode": ("order_code", str),
    "simplebootupmaster": ("simple_boot_up_master", bool),
    "simplebootupslave": ("simple_boot_up_slave", bool),
    "granularity": ("granularity", int),
    "dynamicchannelssupported": ("dynamic_channels_supported", int),
    "groupmessaging": ("group_messaging", bool),
    "nrofrxpdo": ("nr_of_rx_pdo", int),
    "nroftxpdo": ("nr_of_tx_pdo", int),
    "lss_supported": ("lss_supported", bool),
    "compactpdo": ("compact_pdo", int),
}
_COMMISSIONING_KEYS = {
    "nodeid": ("node_id", int),
    "nodename": ("node_name", str),
    "baudrate": ("baudrate", int),
    "netnumber": ("net_number", int),
    "networkname": ("network_name", str),
    "canopenmanager": ("canopen_manager", bool),
    "lss_serialnumber": ("lss_serial_number", int),
}


class _Section:
    __slots__ = ("comments", "end", "key_lines", "keys", "line", "name", "start")

    def __init__(self, name: str, line: int, start: int) -> None:
        self.name = name
        self.line = line  # of the header, 1-based
        self.start = start  # text offset of the line after the header
        self.end = start  # text offset where the section ends
        self.keys: dict[str, str] = {}
        #: Whole-line comments: (the key before it, or None; the line).
        self.comments: list[tuple[str | None, str]] | None = None
        #: The line of each key, kept only once a key appeared twice in the section (so
        #: that a file of repeated keys costs one scan of the section, not one per repeat).
        self.key_lines: dict[str, int] | None = None


class _Loader:
    def __init__(self, path: str, strict: bool) -> None:
        self.path = path
        self.strict = strict
        self.findings: list[Finding] = []
        self.text = ""
        self.by_line: dict[int, _Section] = {}
        #: Comments before the first section.
        self.head: list[tuple[str | None, str]] = []
        #: Comments of the sections that became part of the dictionary, by section key.
        self.comments: dict[str, list[tuple[str | None, str]]] = {}

    # --- findings ---------------------------------------------------------------------------

    def error(self, line: int | None, section: str | None, reason: str) -> None:
        finding = Finding(self.path, line, section, Severity.ERROR, reason)
        if self.strict:
            raise EdsError.from_finding(finding)
        self.findings.append(finding)

    def warning(self, line: int | None, section: str | None, reason: str) -> None:
        self.findings.append(Finding(self.path, line, section, Severity.WARNING, reason))

    def key_line(self, sec: _Section, key: str) -> int:
        """The line of ``key`` in ``sec`` (the header line if it is not there).

        Lines are only looked up for findings, so the tokenizer keeps none: it scans the
        section's stretch of the text again.
        """
        low = key.lower()
        n = len(low)
        for i, raw in enumerate(self.text[sec.start : sec.end].split("\n"), sec.line + 1):
            text = raw.lstrip()
            if text[:n].lower() == low and text[n:].lstrip().startswith("="):
                return i
        return sec.line

    def key_lines(self, sec: _Section) -> dict[str, int]:
        """The line of each key of ``sec`` (lower case, the first one of a name)."""
        found: dict[str, int] = {}
        for i, raw in enumerate(self.text[sec.start : sec.end].split("\n"), sec.line + 1):
            key, sep, _ = raw.partition("=")
            key = key.strip()
            if sep and key and key[0] not in ";#[":
                found.setdefault(key.lower(), i)
        return found

    # --- pass 1: sections -------------------------------------------------------------------

    def tokenize(self, text: str) -> list[_Section]:
        if text.startswith("\ufeff"):
            text = text[1:]
        if "\r" in text and "\n" not in text:
            text = text.replace("\r", "\n")  # old Mac line ends
        self.text = text
        sections: list[_Section] = []
        seen: dict[str, _Section] = {}
        cur: _Section | None = None
        last_key: str | None = None  # the last key of the current section
        no = 0
        size = len(text)
        find = text.find
        strings: dict[str, str] = {}
        intern = strings.setdefault
        # The text is split into lines one stretch at a time, cut before each "[" that starts
        # a line, so that only one section's lines are alive at once and a section header is
        # (nearly always) the first line of its stretch.
        start = 0
        while start < size:
            cut = find("\n[", start)
            end = size if cut < 0 else cut + 1
            lines = text[start:end].split("\n")
            if not lines[-1]:
                lines.pop()  # what follows the stretch's last newline
            # Text offset of the line after the last header found in this stretch and its
            # index in ``lines``: a header's offset is counted on from there (headers that do
            # not start a line, " [1000]", stay in one stretch: counting from the stretch's
            # start for each was quadratic).
            mark, mark_at = start, 0
            for i, raw in enumerate(lines, no + 1):
                line = raw.strip()
                if not line:
                    continue
                first = line[0]
                if first == ";" or first == "#":
                    # Kept with the section it is in, after the key it follows.
                    if cur is None:
                        self.head.append((None, line))
                    elif cur.comments is None:
                        cur.comments = [(last_key, intern(line, line))]
                    else:
                        cur.comments.append((last_key, intern(line, line)))
                    continue
                if first == "[":
                    # Text offsets of this line and of the next one.
                    at = i - no - 1
                    here = mark + sum(len(x) + 1 for x in lines[mark_at:at])
                    after = here + len(raw) + 1
                    mark, mark_at = after, at + 1
                    if cur is not None:
                        cur.end = here
                    last_key = None
                    close = line.find("]")
                    rest = line[close + 1 :].lstrip() if close > 0 else ""
                    name = line[1:close].strip() if close > 0 else ""
                    if not name or (rest and rest[0] not in ";#"):
                        self.error(
                            i,
                            None,
                            f"malformed section header {line!r}: write it as [name] on its "
                            "own line",
                        )
                        cur = _Section("", i, after)  # swallows the keys that follow
                        continue
                    cur = _Section(name, i, after)
                    upper = name.upper()
                    first_sec = seen.get(upper)
                    if first_sec is not None:
                        self.error(
                            i,
                            name,
                            f"section [{name}] appears again (first at line {first_sec.line}); "
                            "remove or merge the duplicate — this copy is ignored",
                        )
                        continue
                    seen[upper] = cur
                    sections.append(cur)
                    self.by_line[i] = cur
                    continue
                key, sep, value = line.partition("=")
                if cur is None:
                    # Before any section the file may be no EDS at all (a network file's
                    # eds: naming another file): its lines are not quoted.
                    self.error(i, None, "text before the first [section]: an EDS starts with one")
                    continue
                if not sep:
                    self.error(
                        i,
                        cur.name,
                        f"line {clip(repr(line), 80)} is not key=value, a [section] or a ;comment",
                    )
                    continue
                key = key.rstrip()
                keys = cur.keys
                if key in keys:
                    key_lines = cur.key_lines
                    if key_lines is None:
                        cur.end = end
                        key_lines = cur.key_lines = self.key_lines(cur)
                    self.error(
                        i,
                        cur.name,
                        f"key {key} appears twice in the section (first at line "
                        f"{key_lines.get(key.lower(), cur.line)}); keep one — the first value "
                        "is used",
                    )
                    continue
                value = value.lstrip()
                # One string object per distinct key and value: files repeat them a lot.
                last_key = intern(key, key)
                keys[last_key] = intern(value, value)
                if cur.key_lines is not None:
                    cur.key_lines.setdefault(key.lower(), i)
            no += len(lines)
            start = end
            if cur is not None:
                cur.end = end
        return sections

    # --- pass 2: building -------------------------------------------------------------------

    def keep_comments(self, sec: _Section, key: str) -> None:
        """The comments of ``sec``, a section of the dictionary written as [``key``]."""
        if sec.comments is not None:
            self.comments[key] = sec.comments

    def build(self, sections: list[_Section], node_id: int | None) -> ObjectDictionary:
        od = ObjectDictionary()
        od.path = self.path
        objects: dict[int, _Section] = {}
        subs: dict[int, dict[int, _Section]] = {}
        aux: dict[tuple[int, str], _Section] = {}
        lists: list[_Section] = []
        dummy: _Section | None = None
        for sec in sections:
            upper = sec.name.upper()
            m = _OBJ_SECTION.match(upper)
            if m is not None:
                index = int(m.group(1), 16)
                sub_text = m.group(2)
                if sub_text is not None:
                    sub = int(sub_text, 16)
                    if sub > 0xFF:
                        self.error(
                            sec.line,
                            sec.name,
                            f"sub-index 0x{sub:X} is beyond 0xFF; this section is ignored",
                        )
                        continue
                    group = subs.setdefault(index, {})
                    if sub in group:
                        self.error(
                            sec.line,
                            sec.name,
                            f"duplicate sub-object: sub-index {sub} of 0x{index:04X} is already "
                            f"defined by [{group[sub].name}] at line {group[sub].line}; "
                            "this one is ignored",
                        )
                        continue
                    group[sub] = sec
                elif m.group(3) is not None:
                    aux[(index, m.group(3))] = sec
                else:
                    objects[index] = sec
                continue
            if sec.comments is not None:
                self.comments[upper] = sec.comments
            if upper == "FILEINFO":
                od.file_info = self._file_info(sec)
            elif upper == "DEVICEINFO":
                od.device_info = self._device_info(sec)
            elif upper in ("DEVICECOMISSIONING", "DEVICECOMMISSIONING"):
                od.commissioning = self._commissioning(sec)
            elif upper == "DUMMYUSAGE":
                dummy = sec
            elif upper == "COMMENTS":
                od.comments = self._comments(sec, od.comments_extra)
            elif upper in ("MANDATORYOBJECTS", "OPTIONALOBJECTS", "MANUFACTUREROBJECTS"):
                lists.append(sec)
            else:
                od.extra_sections.append((sec.name, list(sec.keys.items())))

        com = od.commissioning
        if node_id is None and com is not None and com.node_id is not None:
            node_id = com.node_id if 1 <= com.node_id <= 127 else None
        od._node_id = node_id
        if com is not None and com.baudrate:
            od.bitrate = com.baudrate * 1000

        for index, sec in objects.items():
            self._object(od, index, sec, subs.pop(index, {}), aux, node_id)
        for index, group in subs.items():
            for sub, sec in group.items():
                self.error(
                    sec.line,
                    sec.name,
                    f"sub-object 0x{index:04X}sub{sub:X} has no object section [{index:04X}]; "
                    "add the object or remove the sub-object",
                )
        for (index, _kind), sec in aux.items():
            obj = od._objects.get(index)
            if not isinstance(obj, (Record, Array)) or obj.compact is None:
                self.warning(
                    sec.line,
                    sec.name,
                    f"[{sec.name}] only applies to an object with CompactSubObj; it is kept "
                    "as an unknown section",
                )
                od.extra_sections.append((sec.name, list(sec.keys.items())))
                self.keep_comments(sec, sec.name.upper())
        if dummy is not None:
            self._dummy_usage(od, dummy)
        self._object_lists(od, lists)
        check_dictionary(od, self._report, self._locate)
        if self.head:
            self.comments[""] = self.head
        od.file_comments = self.comments
        return od

    def _report(self, severity: Severity, var: object, key: str | None, reason: str) -> None:
        line, section = self._locate(var, key)
        if severity is Severity.ERROR:
            self.error(line, section, reason)
        else:
            self.warning(line, section, reason)

    def _locate(self, obj: object, key: str | None) -> tuple[int | None, str | None]:
        line = getattr(obj, "line", None)
        sec = self.by_line.get(line) if line is not None else None
        if sec is None:
            return line, None
        return (self.key_line(sec, key) if key else sec.line), sec.name

    # --- objects ----------------------------------------------------------------------------

    def _keys(self, sec: _Section) -> tuple[dict[str, str], dict[str, str] | None]:
        """Known keys under their canonical spelling, and the unknown ones as written."""
        keys = sec.keys
        if keys.keys() <= _OBJ_KEY_SET:
            return keys, None
        known: dict[str, str] = {}
        extra: dict[str, str] = {}
        for key, value in keys.items():
            canon = _OBJ_KEY_BY_LOWER.get(key.lower())
            if canon is None:
                extra[key] = value
            elif canon in known:
                self.error(
                    self.key_line(sec, key),
                    sec.name,
                    f"key {key} repeats {canon} (keys are case-insensitive); the first is used",
                )
            else:
                known[canon] = value
        return known, extra or None

    def _small_int(self, sec: _Section, key: str, text: str) -> int | None:
        try:
            return parse_int(text)
        except TextError as exc:
            self.error(self.key_line(sec, key), sec.name, f"{key}: {exc.reason}")
            return None

    def _object(
        self,
        od: ObjectDictionary,
        index: int,
        sec: _Section,
        subsecs: dict[int, _Section],
        aux: dict[tuple[int, str], _Section],
        node_id: int | None,
    ) -> None:
        keys, extra = self._keys(sec)
        name = keys.get("ParameterName")
        if name is None:
            self.error(sec.line, sec.name, "ParameterName is missing; every object needs a name")
            name = sec.name
        ot_text = keys.get("ObjectType")
        if not ot_text:
            ot = ObjectType.VAR  # CiA 306: a missing ObjectType means VAR
        else:
            cached = _OT_CACHE.get(ot_text)
            if cached is None:
                number = self._small_int(sec, "ObjectType", ot_text)
                if number is None:
                    return
                try:
                    cached = ObjectType(number)
                except ValueError:
                    self.error(
                        self.key_line(sec, "ObjectType"),
                        sec.name,
                        f"ObjectType {ot_text} is unknown: use 0x7 VAR, 0x8 ARRAY, 0x9 RECORD "
                        "or 0x2 DOMAIN; the object is skipped",
                    )
                    return
                _OT_CACHE[ot_text] = cached
            ot = cached
        if ot in (ObjectType.VAR, ObjectType.DOMAIN, ObjectType.DEFTYPE):
            for sub, subsec in subsecs.items():
                self.error(
                    subsec.line,
                    subsec.name,
                    f"sub-object {sub} belongs to 0x{index:04X}, which is a {ot.name} and has "
                    "no sub-objects; make the object a RECORD or ARRAY or remove this section",
                )
            var = self._variable(sec, keys, index, 0, name, ot, node_id)
            if extra:
                var.extra = extra
            od._add(var)
            self.keep_comments(sec, f"{index:04X}")
            return
        if ot is ObjectType.NULL:
            self.error(sec.line, sec.name, "ObjectType 0 (NULL) objects cannot be described")
            return
        obj: Record | Array = Array(index, name) if ot is ObjectType.ARRAY else Record(index, name)
        obj.object_type = ot
        obj.line = sec.line
        obj.denotation = keys.get("Denotation")
        obj.description = keys.get("Description")
        flags = keys.get("ObjFlags")
        if flags:
            obj.obj_flags = self._small_int(sec, "ObjFlags", flags)
        compact_text = keys.get("CompactSubObj")
        compact = self._small_int(sec, "CompactSubObj", compact_text) if compact_text else None
        sub_number_text = keys.get("SubNumber")
        sub_number = self._small_int(sec, "SubNumber", sub_number_text) if sub_number_text else None
        if compact:
            if compact > 0xFE:
                self.error(
                    self.key_line(sec, "CompactSubObj"),
                    sec.name,
                    f"CompactSubObj={compact} exceeds 254 sub-objects; it is cut to 254",
                )
                compact = 0xFE
            if sub_number:
                self.error(
                    self.key_line(sec, "SubNumber"),
                    sec.name,
                    "both SubNumber and CompactSubObj are given; keep one (CompactSubObj is used)",
                )
            self._compact(od, obj, sec, keys, compact, aux, node_id)
            if extra:
                obj.extra = extra
            for sub, subsec in sorted(subsecs.items()):
                self.warning(
                    subsec.line,
                    subsec.name,
                    f"sub-object section overrides the CompactSubObj description of sub {sub}",
                )
                skeys, sextra = self._keys(subsec)
                sname = skeys.get("ParameterName") or subsec.name
                var = self._variable(subsec, skeys, index, sub, sname, ObjectType.VAR, node_id)
                if sextra:
                    var.extra = sextra
                obj.subindices.pop(sub, None)
                obj._names = {v.name: v for v in obj.subindices.values()}
                obj.add(var)
                self.keep_comments(subsec, f"{index:04X}SUB{sub:X}")
            od._add(obj)
            self.keep_comments(sec, f"{index:04X}")
            return
        leftovers = {k: keys[k] for k in _VAR_ONLY if k in keys}
        if leftovers or extra:
            obj.extra = {**leftovers, **(extra or {})}
        for sub in sorted(subsecs):
            subsec = subsecs[sub]
            skeys, sextra = self._keys(subsec)
            sname_text = skeys.get("ParameterName")
            if sname_text is None:
                self.error(subsec.line, subsec.name, "ParameterName is missing")
            sname = subsec.name if sname_text is None else sname_text
            sot_text = skeys.get("ObjectType")
            sot = ObjectType.VAR
            if sot_text and sot_text not in ("0x7", "7", "0x07"):
                number = self._small_int(subsec, "ObjectType", sot_text)
                if number == ObjectType.DOMAIN:
                    sot = ObjectType.DOMAIN
                elif number is not None and number != ObjectType.VAR:
                    self.error(
                        self.key_line(subsec, "ObjectType"),
                        subsec.name,
                        f"a sub-object must be a VAR (0x7) or DOMAIN (0x2), not {sot_text}",
                    )
            var = self._variable(subsec, skeys, index, sub, sname, sot, node_id)
            if sextra:
                var.extra = sextra
            obj.add(var)
            self.keep_comments(subsec, f"{index:04X}SUB{sub:X}")
        self._check_sub_number(obj, sec, sub_number, subsecs, sub_number_text is not None)
        od._add(obj)
        self.keep_comments(sec, f"{index:04X}")

    def _check_sub_number(
        self,
        obj: Record | Array,
        sec: _Section,
        sub_number: int | None,
        subsecs: dict[int, _Section],
        given: bool,
    ) -> None:
        defined = len(subsecs)
        if sub_number is None:
            if not given:
                self.warning(
                    sec.line,
                    sec.name,
                    f"{obj.object_type.name} 0x{obj.index:04X} gives neither SubNumber nor "
                    f"CompactSubObj; add SubNumber={defined}",
                )
            return
        if sub_number > defined:
            highest = max(subsecs, default=-1)
            gaps = [s for s in range(highest + 1) if s not in subsecs]
            hint = (
                "missing: " + ", ".join(f"[{obj.index:04X}sub{s:X}]" for s in gaps[:8])
                if gaps
                else f"after sub-index {highest}"
            )
            self.error(
                self.key_line(sec, "SubNumber"),
                sec.name,
                f"missing sub-object: SubNumber={sub_number} declares {sub_number} "
                f"sub-objects but {defined} are defined ({hint})",
            )
        elif sub_number < defined:
            self.error(
                self.key_line(sec, "SubNumber"),
                sec.name,
                f"SubNumber mismatch: SubNumber={sub_number} but {defined} sub-objects are "
                f"defined; set SubNumber={defined}",
            )
        if 0 not in subsecs and subsecs:
            self.warning(
                sec.line,
                sec.name,
                "sub-index 0 (the highest sub-index supported) is not defined",
            )

    def _compact(
        self,
        od: ObjectDictionary,
        obj: Record | Array,
        sec: _Section,
        keys: dict[str, str],
        count: int,
        aux: dict[tuple[int, str], _Section],
        node_id: int | None,
    ) -> None:
        index = obj.index
        obj.compact = count
        template = self._variable(sec, keys, index, 1, obj.name, ObjectType.VAR, node_id)
        template.denotation = None
        template.description = None
        template.obj_flags = None
        sub0 = Variable(index, 0, "NrOfObjects", DataType.UNSIGNED8, Access.RO)
        sub0._default = count
        sub0.line = sec.line
        obj.add(sub0)
        base = obj.name
        for sub in range(1, count + 1):
            var = _clone(template)
            var.subindex = sub
            var.name = f"{base}{sub}"
            obj.add(var)
        names = aux.pop((index, "NAME"), None)
        if names is not None:
            for sub, text, _key in self._numbered(names, count):
                var = obj.subindices[sub]
                obj._names.pop(var.name, None)
                var.name = text
                obj._names[text] = var
        values = aux.pop((index, "VALUE"), None)
        if values is not None:
            for sub, text, key in self._numbered(values, count):
                var = obj.subindices[sub]
                var._param_raw = text
                var._rel &= ~REL_PARAM
                if var.declared_type is not None:
                    continue
                try:
                    value, rel = parse_value(var.data_type, text, node_id)
                except TextError as exc:
                    self.error(self.key_line(values, key), values.name, f"sub {sub}: {exc.reason}")
                    var._param = None
                    continue
                var._param = value
                if rel:
                    var._rel |= REL_PARAM
                if value is not None:
                    self._within_limits(var, value, key, values, self.key_line(values, key))
        denotations = aux.pop((index, "DENOTATION"), None)
        if denotations is not None:
            for sub, text, _key in self._numbered(denotations, count):
                obj.subindices[sub].denotation = text
        for suffix, used in (("NAME", names), ("VALUE", values), ("DENOTATION", denotations)):
            if used is not None:
                self.keep_comments(used, f"{index:04X}{suffix}")

    def _numbered(self, sec: _Section, count: int) -> list[tuple[int, str, str]]:
        """``N=text`` entries of a [xxxxName]/[xxxxValue]/[xxxxDenotation] section, with keys."""
        out: list[tuple[int, str, str]] = []
        declared: int | None = None
        for key, text in sec.keys.items():
            if key.lower() == "nrofentries":
                declared = self._small_int(sec, key, text)
                continue
            try:
                sub = int(key, 10)
            except ValueError:
                self.error(
                    self.key_line(sec, key),
                    sec.name,
                    f"key {key!r} is not a sub-index (1..{count})",
                )
                continue
            if not 1 <= sub <= count:
                self.error(
                    self.key_line(sec, key),
                    sec.name,
                    f"sub-index {sub} is outside 1..{count} (CompactSubObj)",
                )
                continue
            out.append((sub, text, key))
        if declared is not None and declared != len(out):
            self.warning(
                self.key_line(sec, "NrOfEntries"),
                sec.name,
                f"NrOfEntries={declared} but {len(out)} entries follow",
            )
        return out

    def _variable(
        self,
        sec: _Section,
        keys: dict[str, str],
        index: int,
        sub: int,
        name: str,
        ot: ObjectType,
        node_id: int | None,
    ) -> Variable:
        dt_text = keys.get("DataType")
        declared: int | None = None
        opaque = False  # values are kept as text only: the type is unknown
        dt: DataType | None = _DT_CACHE.get(dt_text) if dt_text else None
        if dt is None:
            if not dt_text:
                dt = DataType.DOMAIN
                if ot is not ObjectType.DOMAIN:
                    opaque = True
                    self.error(
                        sec.line,
                        sec.name,
                        "DataType is missing: add e.g. DataType=0x0007 for UNSIGNED32 "
                        "(handled as DOMAIN, raw bytes)",
                    )
            else:
                number = self._small_int(sec, "DataType", dt_text)
                try:
                    dt = DataType(-1 if number is None else number)
                    _DT_CACHE[dt_text] = dt
                except ValueError:
                    dt = DataType.DOMAIN
                    opaque = True
                    if number is not None:
                        declared = number
                        self.error(
                            self.key_line(sec, "DataType"),
                            sec.name,
                            f"unknown data type 0x{number:04X}: CiA 301 basic types are "
                            "0x0001..0x001B (handled as DOMAIN, raw bytes)",
                        )
        acc_text = keys.get("AccessType")
        access = _ACCESS.get(acc_text) if acc_text else None
        if access is None:
            if acc_text:
                access = _ACCESS.get(acc_text.strip().lower())
            if access is None:
                line = self.key_line(sec, "AccessType")
                if acc_text:
                    self.error(
                        line,
                        sec.name,
                        f"AccessType {acc_text!r} is unknown: use ro, wo, rw, rwr, rww or const "
                        "(read as rw)",
                    )
                elif ot is not ObjectType.DOMAIN:
                    self.error(line, sec.name, "AccessType is missing (read as rw)")
                access = Access.RW
        pdo_text = keys.get("PDOMapping")
        pdo = False
        if pdo_text:
            cached = _BOOL_CACHE.get(pdo_text)
            if cached is None:
                number = self._small_int(sec, "PDOMapping", pdo_text)
                cached = bool(number)
                if number is not None:
                    if number not in (0, 1):
                        self.warning(
                            self.key_line(sec, "PDOMapping"),
                            sec.name,
                            f"PDOMapping={pdo_text} should be 0 or 1 (read as 1)",
                        )
                    else:
                        _BOOL_CACHE[pdo_text] = cached
            pdo = cached
        var = Variable(index, sub, name, dt, access, pdo)
        var.object_type = ot
        var.line = sec.line
        if declared is not None:
            var.declared_type = declared
        low = keys.get("LowLimit")
        high = keys.get("HighLimit")
        default = keys.get("DefaultValue")
        param = keys.get("ParameterValue")
        if opaque:
            var._low_raw, var._high_raw, var._default_raw, var._param_raw = (
                low,
                high,
                default,
                param,
            )
        else:
            if low is not None:
                var._low_raw = low
                var._low = self._value(var, sec, "LowLimit", low, node_id, REL_LOW)
            if high is not None:
                var._high_raw = high
                var._high = self._value(var, sec, "HighLimit", high, node_id, REL_HIGH)
            if default is not None:
                var._default_raw = default
                var._default = self._value(var, sec, "DefaultValue", default, node_id, REL_DEFAULT)
            if param is not None:
                var._param_raw = param
                var._param = self._value(var, sec, "ParameterValue", param, node_id, REL_PARAM)
            if var._low is not None or var._high is not None:
                self._limits(var, sec)
        if not _OPTIONAL_KEYS.isdisjoint(keys):
            self._optional_keys(var, sec, keys)
        return var

    def _optional_keys(self, var: Variable, sec: _Section, keys: dict[str, str]) -> None:
        var.denotation = keys.get("Denotation")
        var.description = keys.get("Description")
        var.unit = keys.get("Unit")
        factor = keys.get("Factor")
        if factor is not None:
            try:
                var.factor = float(factor)
            except ValueError:
                self.warning(
                    self.key_line(sec, "Factor"),
                    sec.name,
                    f"Factor {factor!r} is not a number; it is kept as text",
                )
                var.extra = {**(var.extra or {}), "Factor": factor}
        flags = keys.get("ObjFlags")
        if flags:
            var.obj_flags = self._small_int(sec, "ObjFlags", flags)

    def _value(
        self, var: Variable, sec: _Section, key: str, text: str, node_id: int | None, bit: int
    ) -> object:
        dt = var.data_type
        if dt in INT_INFO and "$" not in text:
            try:  # the common case, inline
                number = int(text, 0)
            except ValueError:
                pass
            else:
                lo, hi, _signed, _bits = INT_INFO[dt]
                if lo <= number <= hi:
                    return number
        try:
            value, relative = parse_value(dt, text, node_id)
        except TextError as exc:
            self.error(self.key_line(sec, key), sec.name, f"{key}: {exc.reason}")
            return None
        if relative:
            var._rel |= bit
        if dt is DataType.VISIBLE_STRING and not (value.isascii() and value.isprintable()):
            self.warning(
                self.key_line(sec, key),
                sec.name,
                f"{key} {value!r} has characters outside visible ASCII (0x20..0x7E)",
            )
        return value

    def _limits(self, var: Variable, sec: _Section) -> None:
        low, high = var._low, var._high
        if low is not None and high is not None and _lt(high, low):
            self.error(
                self.key_line(sec, "LowLimit"),
                sec.name,
                f"LowLimit {low!r} is above HighLimit {high!r}",
            )
            return
        default, param = var._default, var._param
        try:  # the common case, inline: values of one type within the limits
            if (default is None or _inside(default, low, high)) and (
                param is None or _inside(param, low, high)
            ):
                return
        except TypeError:
            pass
        for key, value in (("DefaultValue", default), ("ParameterValue", param)):
            if value is not None:
                self._within_limits(var, value, key, sec, None)

    def _within_limits(
        self, var: Variable, value: object, key: str, sec: _Section, line: int | None
    ) -> None:
        low, high = var._low, var._high
        if low is not None and _lt(value, low):
            reason = f"{key} {value!r} is below LowLimit {low!r}"
        elif high is not None and _lt(high, value):
            reason = f"{key} {value!r} is above HighLimit {high!r}"
        else:
            return
        self.error(line if line is not None else self.key_line(sec, key), sec.name, reason)

    # --- other sections ---------------------------------------------------------------------

    def _file_info(self, sec: _Section) -> FileInfo:
        info = FileInfo()
        for key, value in sec.keys.items():
            attr = _FILE_INFO_KEYS.get(key.lower())
            if attr is None or getattr(info, attr) is not None:
                info.extra[key] = value
            else:
                setattr(info, attr, value)
        return info

    def _typed(
        self,
        sec: _Section,
        key: str,
        value: str,
        kind: type,
        extra: dict[str, str],
    ) -> object:
        if kind is str:
            return value
        if not value.strip():
            return None
        try:
            number = parse_int(value)
        except TextError as exc:
            self.warning(self.key_line(sec, key), sec.name, f"{key}: {exc.reason}; kept as text")
            extra[key] = value
            return None
        return bool(number) if kind is bool else number

    def _device_info(self, sec: _Section) -> DeviceInfo:
        info = DeviceInfo()
        for key, value in sec.keys.items():
            upper = key.upper()
            spec = _DEVICE_INFO_KEYS.get(key.lower())
            if spec is not None and getattr(info, spec[0]) is None:
                setattr(info, spec[0], self._typed(sec, key, value, spec[1], info.extra))
                continue
            m = _BAUD_KEY.match(upper)
            if m is not None:
                typed = self._typed(sec, key, value, bool, info.extra)
                if typed:
                    info.baud_rates.add(int(m.group(1)))
                continue
            info.extra[key] = value
        return info

    def _commissioning(self, sec: _Section) -> Commissioning:
        com = Commissioning(section=sec.name)
        for key, value in sec.keys.items():
            spec = _COMMISSIONING_KEYS.get(key.lower())
            if spec is None or getattr(com, spec[0]) is not None:
                com.extra[key] = value
                continue
            typed = self._typed(sec, key, value, spec[1], com.extra)
            setattr(com, spec[0], typed)
            if spec[0] == "node_id" and typed is not None and not 1 <= typed <= 127:  # type: ignore[operator]
                self.error(
                    self.key_line(sec, key),
                    sec.name,
                    f"NodeID {value} is outside 1..127; $NODEID values stay unresolved",
                )
        return com

    def _comments(self, sec: _Section, extra: dict[str, str]) -> list[str]:
        lines: dict[int, str] = {}
        declared: int | None = None
        for key, value in sec.keys.items():
            upper = key.upper()
            if upper == "LINES":
                declared = self._typed(sec, key, value, int, {})  # type: ignore[assignment]
                continue
            m = _LINE_KEY.match(upper)
            if m is None:
                self.warning(
                    self.key_line(sec, key),
                    sec.name,
                    f"key {key} is not LineN; it is kept as written",
                )
                extra[key] = value
                continue
            lines[int(m.group(1))] = value
        # the lines given make the comment: a Lines= count only gets a warning (a count
        # from a file is never what memory is allocated by)
        count = max(lines, default=0)
        if declared is not None and declared != len(lines):
            self.warning(
                self.key_line(sec, "Lines"),
                sec.name,
                f"Lines={declared} but {len(lines)} LineN keys are given",
            )
        return [lines.get(i, "") for i in range(1, count + 1)]

    def _dummy_usage(self, od: ObjectDictionary, sec: _Section) -> None:
        for key, value in sec.keys.items():
            m = _DUMMY_KEY.match(key.upper())
            if m is None:
                self.warning(
                    self.key_line(sec, key),
                    sec.name,
                    f"key {key} is not DummyNNNN; it is kept as written",
                )
                od.dummy_usage_extra[key] = value
                continue
            code = int(m.group(1), 16)
            try:
                enabled = bool(parse_int(value)) if value.strip() else False
            except TextError as exc:
                self.error(
                    self.key_line(sec, key), sec.name, f"{key}: {exc.reason}; it is kept as written"
                )
                od.dummy_usage_extra[key] = value
                continue
            od.dummy_usage[code] = enabled
            if not enabled or code in od._objects:
                continue
            try:
                dt = DataType(code)
            except ValueError:
                self.warning(
                    self.key_line(sec, key),
                    sec.name,
                    f"{key}: 0x{code:04X} is not a basic data type",
                )
                continue
            var = dummy_variable(code, dt)
            var.line = sec.line
            od._add(var)
            od._dummies.add(code)

    def _object_lists(self, od: ObjectDictionary, lists: list[_Section]) -> None:
        listed: set[int] = set()
        for sec in lists:
            declared: int | None = None
            entries: list[int] = []
            for key, value in sec.keys.items():
                if key.lower() == "supportedobjects":
                    declared = self._small_int(sec, key, value)
                    continue
                try:
                    parse_int(key)
                    entries.append(parse_int(value))
                except TextError as exc:
                    self.error(self.key_line(sec, key), sec.name, f"{key}={value}: {exc.reason}")
            if declared is not None and declared != len(entries):
                self.warning(
                    self.key_line(sec, "SupportedObjects"),
                    sec.name,
                    f"SupportedObjects={declared} but {len(entries)} objects are listed",
                )
            missing = [i for i in entries if i not in od._objects]
            if missing:
                self.warning(
                    sec.line,
                    sec.name,
                    "listed but not defined: " + _indices(missing),
                )
            listed.update(entries)
        if not lists:
            return
        by_list: dict[str, list[int]] = {}
        for index in sorted(od._objects):
            if index not in listed and index not in od._dummies:
                by_list.setdefault(_list_name(index), []).append(index)
        for name, unlisted in by_list.items():
            first = od._objects[unlisted[0]]
            line, section = self._locate(first, None)
            self.warning(
                line, section, f"defined but not listed in [{name}]: " + _indices(unlisted)
            )


def _list_name(index: int) -> str:
    """The CiA 306 object list an object belongs in."""
    if index in (0x1000, 0x1001, 0x1018):
        return "MandatoryObjects"
    if 0x2000 <= index <= 0x5FFF:
        return "ManufacturerObjects"
    return "OptionalObjects"


def _indices(indices: list[int]) -> str:
    shown = ", ".join(f"0x{i:04X}" for i in indices[:12])
    return shown + (f" and {len(indices) - 12} more" if len(indices) > 12 else "")


def _inside(value: Any, low: Any, high: Any) -> bool:
    return (low is None or value >= low) and (high is None or value <= high)


def _lt(a: object, b: object) -> bool:
    try:
        return bool(a < b)  # type: ignore[operator]
    except TypeError:
        return False


def _clone(var: Variable) -> Variable:
    new = Variable.__new__(Variable)
    for slot in Variable.__slots__:
        setattr(new, slot, getattr(var, slot))
    if var.extra is not None:
        new.extra = dict(var.extra)
    return new


def _sort_key(f: Finding) -> tuple[int, int]:
    return (0, f.line) if f.line is not None else (1, 0)


def loads(
    text: str,
    node_id: int | None = None,
    *,
    strict: bool = False,
    path: str = "<string>",
) -> ObjectDictionary:
    """Read EDS/DCF text. ``node_id`` overrides [DeviceComissioning] NodeID for ``$NODEID``."""
    if node_id is not None and not 1 <= node_id <= 127:
        raise EdsError(path, None, None, f"node id {node_id} is outside 1..127")
    loader = _Loader(path, strict)
    sections = loader.tokenize(text)
    od = loader.build(sections, node_id)
    if not od._objects:
        # Not an EDS: what its lines would say is noise, and no line of it is shown (a
        # network file's eds: may name any file).
        loader.findings = []
        loader.error(
            None,
            None,
            "the file defines no objects: it is not an EDS or DCF (CiA 306 needs at least "
            "1000h, 1001h and 1018h)",
        )
    loader.findings.sort(key=_sort_key)
    od.findings = loader.findings
    return od


def load(
    path: str | os.PathLike[str],
    node_id: int | None = None,
    *,
    strict: bool = False,
) -> ObjectDictionary:
    """Read an EDS or DCF file (UTF-8, or Latin-1 when it is not valid UTF-8)."""
    name = os.fspath(path)
    try:
        data = Path(name).read_bytes()
    except OSError as exc:
        raise EdsError(name, None, None, f"cannot read the file: {exc.strerror}") from None
    try:
        text = data.decode("utf-8")
        fallback = False
    except UnicodeDecodeError:
        text = data.decode("latin-1")
        fallback = True
    del data  # not needed while reading: halves the peak memory of large files
    od = loads(text, node_id, strict=strict, path=name)
    if fallback:
        od.findings.insert(
            0,
            Finding(name, None, None, Severity.WARNING, "not UTF-8; read as Latin-1"),
        )
    return od

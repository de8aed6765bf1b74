"""The shape of the code base, guarded (issue 41): the pre-defined connection set is spelled
in one module; no new public class takes a name another one has; no new module builds its
own SDO client. The names and modules allowed today are the issue's debt: each entry goes
as that issue lands, and none may be added."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from cobus.proto import connection_set as cs

SRC = Path(__file__).resolve().parent.parent / "src" / "cobus"
#: A connection-set base added to or taken from a node-ID (or a COB-ID) as a literal.
PLUS = re.compile(r"0x0*(80|180|200|280|300|380|400|480|500|580|600|700)\s*\+\s*[A-Za-z_(]")
MINUS = re.compile(r"[A-Za-z_)\]]\s*-\s*0x0*(80|180|200|580|600|700)\b")
#: A chained comparison with an edge of the set as a literal (``0x581 <= cob <= 0x5FF``).
_EDGE = r"0x(080|081|0FF|17F|180|181|1FF|57F|580|581|5FF|600|601|67F|700|701|77F)\b"
_COB = r"[\w.]*(?:cob|can_id|ident)[\w.]*"
RANGE = re.compile(rf"{_EDGE}\s*<=?\s*{_COB}\s*<=?|<=?\s*{_COB}\s*<=?\s*{_EDGE}", re.I)


def test_no_connection_set_literal_outside_its_module() -> None:
    found = [
        f"{path.relative_to(SRC)}:{n}: {line.strip()}"
        for path in sorted(SRC.rglob("*.py"))
        if path.name != "connection_set.py"
        for n, line in enumerate(path.read_text().splitlines(), 1)
        if PLUS.search(line) or MINUS.search(line) or RANGE.search(line)
    ]
    assert not found, "use cobus.proto.connection_set:\n" + "\n".join(found)


#: Class names defined more than once today (issue 41 gives each idea one name).
#: The one module that builds an SDO client: the network's transports, shared per COB-ID pair.
SDO_CLIENT_BUILDERS = {"runtime/sdo_transport.py"}


def test_no_class_name_is_defined_twice() -> None:
    where: dict[str, list[str]] = {}
    for path in sorted(SRC.rglob("*.py")):
        for name in re.findall(r"^class ([A-Z][A-Za-z0-9]*)", path.read_text(), re.M):
            where.setdefault(name, []).append(str(path.relative_to(SRC)))
    shared = {name: files for name, files in where.items() if len(files) > 1}
    assert not shared, f"one name per idea: {shared}"


def test_a_blocking_twin_is_named_after_its_async_class() -> None:
    """X is the twin of AsyncX; BlockingX the twin of an async class named X (see cobus)."""
    twins = []
    for path in sorted(SRC.rglob("*.py")):
        found = re.findall(
            r"^class (\w+)\(BlockingTwin, twin_of=([\w.]+)\)", path.read_text(), re.M
        )
        twins += [(name, of.rpartition(".")[2]) for name, of in found]
    assert len(twins) > 20
    wrong = [(n, of) for n, of in twins if of != f"Async{n}" and n != f"Blocking{of}"]
    assert not wrong, wrong


def test_no_new_module_builds_an_sdo_client() -> None:
    builders = {
        str(path.relative_to(SRC))
        for path in SRC.rglob("*.py")
        if re.search(r"(?<!class )\bSdoClient\(", path.read_text())
    }
    assert builders == SDO_CLIENT_BUILDERS


def test_no_private_name_of_the_remote_node_is_used_from_another_file() -> None:
    """The blocking facade and the master use the SDO channel's public face."""
    private = set(
        re.findall(r"^\s*(?:def|class) (_[a-z]\w*)", (SRC / "runtime/remote.py").read_text(), re.M)
    )
    private |= set(re.findall(r"^(_[A-Za-z]\w*)\b", (SRC / "runtime/remote.py").read_text(), re.M))
    users = {}
    for path in sorted(SRC.rglob("*.py")):
        if path.name == "remote.py" and path.parent.name == "runtime":
            continue
        text = path.read_text()
        used = sorted(
            n for n in private if re.search(rf"(?:_remote|remote)\.{n}\b|\.aio\.{n}\b", text)
        )
        if used:
            users[str(path.relative_to(SRC))] = used
    assert not users, users


#: Where a file of master/ may reach a private name through another object: the port the
#: master hands its nodes (master.py's _NodePort reaches the master's), and the image's
#: views of the one ProcessImage of image.py.
PRIVATE_ALLOWED = {("master.py", "_NodePort"), ("image.py", "Inputs"), ("image.py", "Outputs")}


def foreign_privates(source: str, name: str) -> list[str]:
    """Each ``x._name`` of ``source`` whose ``x`` is not plain ``self``/``cls`` (chains such
    as ``self.master._emit`` included), outside the classes :data:`PRIVATE_ALLOWED` names."""
    tree = ast.parse(source)
    allowed = {cls for file, cls in PRIVATE_ALLOWED if file == name}
    spared: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ClassDef) and node.name in allowed:
            spared |= {id(inner) for inner in ast.walk(node)}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute) or id(node) in spared:
            continue
        attr = node.attr
        if not attr.startswith("_") or attr.startswith("__"):
            continue
        if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
            continue
        found.append(f"{name}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_no_file_of_the_master_uses_another_files_private_names() -> None:
    """The master and its nodes meet through master/_context.py (issue 43): no file of
    ``master/`` reaches a private name through another object."""
    found = []
    for path in sorted((SRC / "master").rglob("*.py")):
        found += foreign_privates(path.read_text(), path.name)
    assert not found, found


def test_a_managed_node_keeps_its_public_face_after_the_split() -> None:
    """Issue 43 moved the boot and the supervision out of ManagedNode: what applications
    read and set on a node still works, and the limits are on its parts."""
    from cobus.master.boot import NodeBoot
    from cobus.master.node import ManagedNode
    from cobus.master.supervision import NodeSupervision

    for name in ("emcy_count", "error_register"):
        prop = getattr(ManagedNode, name)
        assert isinstance(prop, property) and prop.fset is not None, name
    for name in ("emcy_history", "heard_at", "diagnostic", "led", "state", "operational"):
        assert isinstance(getattr(ManagedNode, name), property), name
    assert (NodeSupervision.HEAL_LIMIT, NodeSupervision.HEAL_DELAY) == (3, 0.2)
    assert (NodeBoot.WAKE_LIMIT, NodeBoot.WAKE_WINDOW) == (3, 60.0)


def test_the_private_name_guard_sees_what_it_guards_against() -> None:
    for line in ("node._send_rpdo(layout)", "network._runner", "self.master._emit(e)",
                 "self.context.master._x"):  # fmt: skip
        assert foreign_privates(line, "node.py"), line
    for line in ("cls._x", "self._x.y()", "obj.__class__"):
        assert not foreign_privates(line, "node.py"), line
    assert foreign_privates("self._master._emit(e)", "node.py")  # (only the port may)
    assert not foreign_privates("class _NodePort:\n    x = m._emit", "master.py")
    assert foreign_privates("class Other:\n    x = m._emit", "master.py")


def test_the_guard_sees_what_it_guards_against() -> None:
    for line in ("Frame(0x580 + node, data)", "heard[cob - 0x700] = x", "0x80 + (n)"):
        assert PLUS.search(line) or MINUS.search(line), line
    for line in ("0x2000 + 0x200 * group", 'b"0x180+$NODEID"', "mask = 0x7FF"):
        assert not (PLUS.search(line) or MINUS.search(line)), line


def test_the_connection_set() -> None:
    assert cs.sdo_cob_ids(10) == (0x60A, 0x58A)
    assert cs.emcy_cob_id(1) == 0x081 and cs.error_control_cob_id(127) == 0x77F
    assert [cs.tpdo_cob_id(n, 5) for n in (1, 2, 3, 4)] == [0x185, 0x285, 0x385, 0x485]
    assert [cs.rpdo_cob_id(n, 5) for n in (1, 2, 3, 4)] == [0x205, 0x305, 0x405, 0x505]
    for cob_id, service in (
        (0x000, ("nmt", None)),
        (0x080, ("sync", None)),
        (0x100, ("time", None)),
        (0x7E5, ("lss_master", None)),
        (0x7E4, ("lss_slave", None)),
        (0x08A, ("emcy", 10)),
        (0x38A, ("tpdo3", 10)),
        (0x50A, ("rpdo4", 10)),
        (0x58A, ("sdo_tx", 10)),
        (0x60A, ("sdo_rx", 10)),
        (0x70A, ("error_control", 10)),
        (0x680, ("other", None)),
        (0x700, ("other", None)),
        (0x123 | 0x800, ("other", None)),
    ):
        assert cs.service_of(cob_id) == service, hex(cob_id)


@pytest.mark.parametrize("node", [0, 128, True, "10"])
def test_the_connection_set_covers_node_ids_1_to_127(node: object) -> None:
    with pytest.raises(ValueError, match=r"1\.\.127"):
        cs.sdo_cob_ids(node)  # type: ignore[arg-type]


@pytest.mark.parametrize("number", [0, 5, True])
def test_the_connection_set_covers_pdo_1_to_4(number: object) -> None:
    with pytest.raises(ValueError, match=r"PDO 1\.\.4"):
        cs.tpdo_cob_id(number, 1)  # type: ignore[arg-type]


def test_every_file_the_architecture_map_names_exists() -> None:
    doc = (SRC.parent.parent / "docs" / "architecture.md").read_text()
    named = set(re.findall(r"`(src/cobus/[\w/.]+)`", doc))
    assert len(named) > 40
    missing = sorted(p for p in named if not (SRC.parent.parent / p).exists())
    assert not missing, f"docs/architecture.md names files that are not there: {missing}"


def test_an_emergency_is_one_record_and_its_events_name_its_fields_alike() -> None:
    import warnings

    from cobus.device.events import EmergencySent
    from cobus.master import EmcyRecord
    from cobus.master.events import NodeEmergency
    from cobus.proto.emcy import Emergency
    from cobus.runtime import Emergency as RuntimeEmergency

    assert RuntimeEmergency is Emergency and EmcyRecord is Emergency
    node = NodeEmergency(5, 0x2310, 0x03, b"\x01", "Current")
    sent = EmergencySent(5, 0x2310, 0x03, b"\x02")
    assert node.manufacturer_data == b"\x01" and sent.manufacturer_data == b"\x02"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert node.data == b"\x01" and sent.manufacturer == b"\x02"  # the old names, a release
    assert [w.category for w in caught] == [DeprecationWarning, DeprecationWarning]


def test_a_renamed_class_still_imports_with_a_warning() -> None:
    import warnings

    import cobus.apps.panel as panel
    from cobus.apps.panel import PanelCommand

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert panel.Command is PanelCommand
    assert "cobus.apps.panel.Command is now cobus.apps.panel.PanelCommand" in str(caught[0].message)
    with pytest.raises(AttributeError, match="has no attribute 'Nothing'"):
        panel.Nothing  # noqa: B018

    import cobus.device as device
    import cobus.device.events as events

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert device.PdoLengthError is events.PdoLengthError is device.WrongLengthRpdoReceived
    assert len(caught) == 2 and "is now" in str(caught[0].message)

    import cobus.blocks as blocks

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert blocks.Severity is blocks.AlarmSeverity
    assert "cobus.blocks.Severity is now cobus.blocks.AlarmSeverity" in str(caught[0].message)


#: (module, old name, new name): one name per idea, the old name importable for one release.
RENAMED_CLASSES = [
    ("cobus.runtime.remote", "RemoteNode", "AsyncRemoteNode"),
    ("cobus.runtime.remote", "SdoVariable", "AsyncSdoVariable"),
    ("cobus.runtime.remote", "SdoRecord", "AsyncSdoRecord"),
    ("cobus.runtime.nmt", "RemoteNmt", "AsyncRemoteNmt"),
    ("cobus.runtime.emcy", "RemoteEmcy", "AsyncRemoteEmcy"),
    ("cobus.runtime.pdo", "RemotePdo", "AsyncRemotePdo"),
    ("cobus.runtime.pdo", "PdoSet", "AsyncPdoSet"),
    ("cobus.proto.nmt", "StateChanged", "NmtStateChanged"),
    ("cobus.proto.sync", "SyncLost", "SyncTimedOut"),
    ("cobus.proto.timestamp", "TimeReceived", "TimeStampReceived"),
    ("cobus.sim", "Drive402", "SimulatedDrive402"),
    ("cobus.sim", "Io401", "SimulatedIo401"),
    ("cobus.sim.drive402", "Drive402", "SimulatedDrive402"),
    ("cobus.sim.io401", "Io401", "SimulatedIo401"),
    ("cobus.trace", "Record", "TraceRecord"),
    ("cobus.trace", "NmtCommand", "NmtCommandRecord"),
    ("cobus.trace", "Emergency", "EmergencyRecord"),
    ("cobus.trace.decoder", "Emergency", "EmergencyRecord"),
    ("cobus.runtime", "SyncService", "NetworkSync"),
    ("cobus.runtime.remote", "SyncService", "NetworkSync"),
    ("cobus.runtime.blocking", "BlockingSdo", "BlockingSdoChannel"),
    ("cobus.runtime.blocking", "BlockingNmt", "BlockingNmtMaster"),
    ("cobus.runtime.blocking", "BlockingSync", "BlockingNetworkSync"),
]


@pytest.mark.parametrize(("module", "old", "new"), RENAMED_CLASSES)
def test_an_old_class_name_imports_with_a_warning_naming_the_new_one(
    module: str, old: str, new: str
) -> None:
    import importlib
    import warnings

    mod = importlib.import_module(module)
    assert new in mod.__all__ and old not in mod.__all__
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert getattr(mod, old) is getattr(mod, new)
    assert [w.category for w in caught] == [DeprecationWarning]
    assert f"{module}.{old} is now {module}.{new}" in str(caught[0].message)


def test_a_renamed_name_is_blamed_on_the_users_line_so_python_shows_it() -> None:
    """Python shows a DeprecationWarning only when it is blamed on the user's code: through a
    blocking twin or a rig file's class name, the warning still points at the caller."""
    import warnings

    from cobus.device import add_device
    from cobus.runtime import Network
    from cobus.sim.rig import resolve_kind
    from tests.test_device_support import test_od

    with Network(simulated=True) as net:
        device = add_device(net, 5, test_od())
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            device.send_emergency(0x4210, manufacturer=b"\x01")  # through the blocking twin
            resolve_kind("cobus.sim.drive402:Drive402")
    assert [w.filename for w in caught] == [__file__, __file__]
    assert "manufacturer_data" in str(caught[0].message)
    assert "SimulatedDrive402" in str(caught[1].message)

"""``cobus run NETWORK.yml``: boot and supervise a network with the cobus master, with its panel.

    cobus run line.yml -i socketcan -c can0              # boot, supervise, print the events
    cobus run line.yml --panel                           # and serve the operator panel
    cobus run line.yml --panel --listen 0.0.0.0:8047     # reachable from other machines:
                                                         # reading it and its commands then
                                                         # need the token the address carries
    cobus run line.yml --panel --unix /run/cobus.sock    # also on a Unix socket
    cobus run thesis.yml --parameters zapi=zapi.yml      # the ZAPI's parameters brought to
                                                         # the file at each of its boots
    cobus run thesis.yml --panel --zapi zapi             # a Drive page for the ZAPI inverter
                                                         # (examples/networks/thesis.yml)
    cobus run line.yml --gateway 127.0.0.1:5000          # and the CiA 309-3 gateway beside
                                                         # the master (cobus gateway --help)

The master boots the network the CiA 302 way and supervises it until Ctrl-C (or
``--duration``); each of its events is printed as a line on stderr (``--quiet``: none). On
stop it ends supervision and leaves every node in the NMT state it is in. An alarm handler
takes the master's alarms (with ``--panel`` or ``--history FILE``, where it keeps them).

The panel (``--panel``) runs in the master's own loop and binds 127.0.0.1:8047 unless
``--listen`` says otherwise; bound to another address, the token the URL it prints carries is
needed to read the panel and for every command that writes to the bus (NMT buttons, drive
commands...); ``--open-reads`` lets a view-only screen read it without the token. It shows the
network, the alarms, and a Drive page for each CiA 402 drive of the network file (its device
type 0x...0192) and each ZAPI inverter ``--zapi NODE`` names: nothing is written to a drive
until the operator asks, and its first enable asks for a confirmation. A ZAPI inverter's
handshake (an RPDO1 every SYNC cycle) starts only when the operator starts it on its page;
until then the inverter, which no controller answers, raises alarm 248 CAN BUS KO and waits
in pre-operational (the master, with no heartbeat from it, cannot tell).

``--parameters NODE=FILE`` (by node name or ID, once per node) is the parameter manager at
boot: before the master starts the node, each parameter of FILE (YAML, CSV or DCF, named by
the node's EDS) is read, the ones that differ are written, saved (1010h) and verified; a
failure holds the node back. It writes configuration only: a file that holds a command (a
controlword, a mode, a set-point, an output, what an RPDO carries) is refused. The panel's
Parameters page shows each node's result and a diff against the file.

``--gateway HOST:PORT`` serves the CiA 309-3 gateway on the master's network, in the same
loop: its clients' transfers and the master's queue on one SDO transport per node (neither
aborts the other), objects go by the names of the network file's EDS files. What a client
sends goes to the bus as sent - an NMT stop of a node the master supervises is reported by
the master as any stop. Beyond this host its writes need a token (``COBUS_GATEWAY_TOKEN``,
else a random one it prints).

Exit codes: 0 ran until stopped, 1 the bus cannot be used, 2 bad usage or a bad network file,
3 the panel or the gateway cannot listen there.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import signal
import socket
import sys
from functools import partial
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from cobus._args import add_bus_options, bus_options, host_port, seconds
from cobus.errors import CobusError

__all__ = ["listen_address", "register"]

_EXIT_OK, _EXIT_BUS, _EXIT_USAGE, _EXIT_PANEL = 0, 1, 2, 3
DEFAULT_PORT = 8047


def listen_address(text: str) -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT``, ``PORT`` or ``[V6]:PORT`` as (host, port); host defaults to
    127.0.0.1, port to 8047."""
    text = text.strip()
    if text.isdigit():
        host, port = "127.0.0.1", int(text)
    else:
        try:
            parts = urlsplit("//" + text)
            host = parts.hostname or "127.0.0.1"
            port = DEFAULT_PORT if parts.port is None else parts.port
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r}: give HOST:PORT (127.0.0.1:8047, [::1]:8047, :8047)"
            ) from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r}: the port is 0-65535")
    return host, port


def register(sub: Any) -> None:
    """Add ``cobus run`` to the command line's sub-commands."""
    p: argparse.ArgumentParser = sub.add_parser(
        "run",
        help="boot and supervise a network with the cobus master (and its operator panel)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("network", type=Path, help="the network description (YAML)")
    p.add_argument("--panel", action="store_true", help="serve the operator panel")
    p.add_argument(
        "--listen",
        type=listen_address,
        default=None,
        metavar="HOST:PORT",
        help="where the panel listens (default 127.0.0.1:8047; port 0: any free one)",
    )
    p.add_argument("--unix", metavar="PATH", help="the panel also listens on this Unix socket")
    p.add_argument(
        "--token",
        help="the token the panel needs, to be read and for its commands (default: a random "
        "one, needed only when it listens beyond 127.0.0.1)",
    )
    p.add_argument(
        "--open-reads",
        action="store_true",
        help="anyone who reaches the panel may read it (a view-only screen); commands still "
        "need the token",
    )
    p.add_argument(
        "--history",
        type=Path,
        metavar="FILE",
        help="keep the alarm history in this SQLite file (the panel's Alarms page shows it)",
    )
    p.add_argument(
        "--parameters",
        action="append",
        default=[],
        metavar="NODE=FILE",
        help="bring NODE's parameters to FILE each time it boots (writes what differs, saves; "
        "commands refused); repeat per node",
    )
    p.add_argument(
        "--zapi",
        action="append",
        default=[],
        metavar="NODE",
        help="show NODE (name or ID) as a ZAPI inverter on the panel: its handshake starts "
        "when the operator starts it there; repeat per inverter",
    )
    p.add_argument(
        "--gateway",
        type=partial(host_port, listening=True),
        metavar="HOST:PORT",
        help="serve the CiA 309-3 gateway beside the master (beyond 127.0.0.1 with a token)",
    )
    p.add_argument("--duration", type=seconds, help="stop after this many seconds")
    p.add_argument("--quiet", "-q", action="store_true", help="do not print the master's events")
    add_bus_options(p)
    p.set_defaults(handler=_run)


def _fail(message: str, code: int) -> int:
    print(f"cobus run: {message}", file=sys.stderr)
    return code


def _run(args: argparse.Namespace) -> int:
    from cobus.master import NetworkConfigError, load_network

    panel_options = (args.listen, args.unix, args.token, args.zapi or None, args.open_reads or None)
    if any(option is not None for option in panel_options) and not args.panel:
        return _fail(
            "--listen, --unix, --token, --open-reads and --zapi are options of the panel: "
            "add --panel",
            _EXIT_USAGE,
        )
    if args.listen is None:
        args.listen = ("127.0.0.1", DEFAULT_PORT)
    try:
        config = load_network(args.network)
    except OSError as exc:
        return _fail(f"cannot read {args.network}: {exc.strerror or exc}", _EXIT_USAGE)
    except NetworkConfigError as exc:
        return _fail(str(exc), _EXIT_USAGE)
    try:
        args.parameter_sets = _parameter_sets(args.parameters, config)
    except ValueError as exc:
        return _fail(str(exc), _EXIT_USAGE)
    done: list[str] = []
    try:
        return asyncio.run(_serve(args, config, done))
    except KeyboardInterrupt:
        said = "; ".join(done) or "nothing had started"
        print(f"\ncobus run: stopped by Ctrl-C: {said}", file=sys.stderr)
        return _EXIT_OK


def _parameter_sets(given: list[str], config: Any) -> dict[int, Any]:
    """``NODE=FILE`` options as parameter sets by node-ID, each read with the node's EDS
    (ValueError says what is wrong: the node, the file, every problem in it)."""
    from cobus.blocks.parameters import ParameterFileError, load_parameters
    from cobus.od import CommandObjects

    by_name = {node.name: node for node in config.nodes.values()}
    sets: dict[int, Any] = {}
    for text in given:
        key, sep, file = text.partition("=")
        if not sep or not key.strip() or not file.strip():
            raise ValueError(f"--parameters {text!r}: give NODE=FILE (zapi=zapi.yml, 8=zapi.yml)")
        key = key.strip()
        node = by_name.get(key)
        if node is None and key.isdigit():
            node = config.nodes.get(int(key))
        if node is None:
            known = ", ".join(f"{n.name} ({n.node_id})" for n in config.nodes.values())
            raise ValueError(f"--parameters {text}: no node {key!r} in the network ({known})")
        if node.node_id in sets:
            raise ValueError(f"--parameters: {node.name} is given twice")
        try:
            sets[node.node_id] = load_parameters(file.strip(), od=node.od)
        except OSError as exc:
            raise ValueError(
                f"--parameters {text}: cannot read {file}: {exc.strerror or exc}"
            ) from None
        except ParameterFileError as exc:
            raise ValueError(f"--parameters {text}: {exc}") from None
        save = sets[node.node_id].save
        if save is not None and save.index != 0x1010:
            raise ValueError(
                f"--parameters {text}: its save command writes 0x{save.index:04X}; a node is "
                "told to save on 1010h (store parameters) only"
            )
        commands = CommandObjects(node.od)
        found = [
            f"{param.address} {param.name} ({why})"
            for param in sets[node.node_id]
            if (why := commands.reason(param.index, param.subindex)) is not None
        ]
        if found:
            raise ValueError(
                f"--parameters {text}: writing it would command {node.name} ("
                + "; ".join(found)
                + "): a parameter file holds configuration only - take these out"
            )
    return sets


async def _serve(args: argparse.Namespace, config: Any, done: list[str]) -> int:
    from cobus.runtime import AsyncNetwork

    network = AsyncNetwork(**bus_options(args))
    try:
        await network.connect()
    except (CobusError, OSError, ValueError) as exc:
        return _fail(f"cannot open the bus: {exc}", _EXIT_BUS)
    # SIGTERM (systemd, docker stop) ends the run as Ctrl-C does: every step below undone
    loop = asyncio.get_running_loop()
    main = asyncio.current_task()
    terminated: list[bool] = []

    def terminate() -> None:
        terminated.append(True)
        if main is not None:
            main.cancel()

    with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
        loop.add_signal_handler(signal.SIGTERM, terminate)
    try:
        async with contextlib.AsyncExitStack() as undo:
            undo.push_async_callback(network.disconnect)
            return await _supervise(args, config, network, undo, done)
    except asyncio.CancelledError:
        if not terminated:
            raise  # Ctrl-C: asyncio.run turns it into KeyboardInterrupt, _run says what was done
        print("cobus run: stopped by SIGTERM: " + "; ".join(done), file=sys.stderr)
        return _EXIT_OK
    finally:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.remove_signal_handler(signal.SIGTERM)


async def _serve_gateway(
    args: argparse.Namespace,
    master: Any,
    network: Any,
    undo: contextlib.AsyncExitStack,
    done: list[str],
) -> int | None:
    """The CiA 309-3 gateway on the master's network (None: serving; else the exit code)."""
    from cobus.apps._serving import gateway_token
    from cobus.apps.gateway import GatewayCore, GatewayServer

    host, port = args.gateway
    try:
        token, drawn = gateway_token(None, [host])
    except ValueError as exc:
        return _fail(f"COBUS_GATEWAY_TOKEN: {exc}", _EXIT_USAGE)
    if drawn:
        print(f"cobus run: gateway clients write after: auth {token}", flush=True)
    dictionaries = {
        (1, node_id): node.config.od
        for node_id, node in master.nodes.items()
        if node.config.od is not None
    }
    core = GatewayCore({1: network}, token=token, dictionaries=dictionaries)
    for node_id, node in master.nodes.items():
        core.in_use[(1, node_id)] = f"the master's node {node.config.name}"
    if master.config.master.node_id is not None:
        core.in_use[(1, master.config.master.node_id)] = "the master's own node-ID"
    server = GatewayServer(core, host, port)
    try:
        await server.start()
    except OSError as exc:
        return _fail(f"the gateway cannot listen on {host}:{port}: {exc.strerror or exc}",
                     _EXIT_PANEL)  # fmt: skip

    async def stop_gateway() -> None:
        await server.stop()
        done.append("the gateway closed")

    undo.push_async_callback(stop_gateway)
    print(f"cobus run: the gateway serves net 1 on {server.address}", flush=True)
    return None


async def _supervise(
    args: argparse.Namespace,
    config: Any,
    network: Any,
    undo: contextlib.AsyncExitStack,
    done: list[str],
) -> int:
    """Start the master (and the alarm handler, the panel), each undone by ``undo`` in the
    reverse order, whatever fails; run until the duration is over or the task is cancelled."""
    from cobus.apps.panel import (
        Panel,
        PanelError,
        serve_alarms,
        serve_master,
        serve_parameters,
        serve_trace,
    )
    from cobus.apps.panel.drives import serve_cia402_drives, serve_zapi
    from cobus.blocks.alarms import AlarmHandler
    from cobus.blocks.param_manager import Parameterise
    from cobus.master import Master, MasterEvent
    from cobus.profiles.zapi import AsyncZapiDrive, ZapiError

    master = Master(network, config)
    for node_id, chosen in args.parameter_sets.items():
        master.add_boot_step(node_id, Parameterise(chosen))

    async def stop_master() -> None:
        await master.stop()
        done.append("supervision ended, every node left in its NMT state")

    undo.push_async_callback(stop_master)
    started = network.time()

    def said(event: MasterEvent) -> None:
        print(f"{network.time() - started:9.3f} s  {event}", file=sys.stderr)

    if not args.quiet:
        master.add_listener(said)
    alarms = None
    if args.panel or args.history is not None:
        try:
            alarms = AlarmHandler(args.history, clock=network.time)
        except CobusError as exc:
            return _fail(str(exc), _EXIT_USAGE)
        undo.callback(alarms.close)
        alarms.attach_master(master)
        if alarms.history_moved is not None:
            print(
                f"cobus run: the alarm history was damaged; moved to {alarms.history_moved}",
                file=sys.stderr,
            )
    if args.panel:
        assert alarms is not None
        host, port = args.listen
        try:
            panel = Panel(
                host=host,
                port=port,
                unix=args.unix,
                token=args.token,
                clock=network.time,
                title=args.network.stem,
                open_reads=args.open_reads,
            )
        except PanelError as exc:
            return _fail(str(exc), _EXIT_USAGE)
        undo.callback(serve_master(panel, master).close)
        undo.callback(serve_alarms(panel, alarms).close)
        serve_parameters(panel, master)
        undo.callback(serve_trace(panel, network, config).close)
        for view in serve_cia402_drives(panel, master):
            view.start()
            undo.callback(view.close)
        zapis: dict[int, str] = {}
        for key in args.zapi:
            try:
                node = master.node(int(key) if key.isdigit() else key)
            except KeyError as exc:
                return _fail(f"--zapi {key}: {exc.args[0] if exc.args else exc}", _EXIT_USAGE)
            if node.node_id in zapis:
                return _fail(f"--zapi: {node.name} is given twice", _EXIT_USAGE)
            zapis[node.node_id] = key
        for node_id, key in zapis.items():
            node = master.nodes[node_id]
            try:
                AsyncZapiDrive(master, node.node_id).close()  # (its PDOs checked, nothing sent)
            except ZapiError as exc:
                return _fail(
                    f"--zapi {key}: {node.name} does not look like a ZAPI inverter in the "
                    f"network file: {str(exc).split(' (', 1)[0]}",
                    _EXIT_USAGE,
                )
            view = serve_zapi(panel, master, node.node_id, on_start=alarms.attach_zapi)
            undo.callback(view.close)
        try:
            await panel.start()
        except PanelError as exc:
            return _fail(str(exc), _EXIT_PANEL)

        async def stop_panel() -> None:
            await panel.stop()
            done.append("the panel closed")

        undo.push_async_callback(stop_panel)
        print(f"cobus run: the panel is at {panel.url}", flush=True)
        if host in ("0.0.0.0", "::", ""):
            print(
                f"cobus run: ({host or '*'} is every interface: from another machine, open it "
                f"with this machine's name or address, e.g. {socket.gethostname()})",
                flush=True,
            )
        if args.unix:
            print(f"cobus run: and on the Unix socket {args.unix}", flush=True)
        if panel.reads_need_token:
            print("cobus run: reading the panel needs the token in that address", flush=True)
        elif panel.needs_token:
            print("cobus run: commands from the panel need the token in that address", flush=True)
    if args.gateway is not None:
        code = await _serve_gateway(args, master, network, undo, done)
        if code is not None:
            return code
    master.start()
    done.append(f"the master supervised {len(master.nodes)} node(s)")
    print(
        f"cobus run: booting {len(master.nodes)} node(s) of {args.network} "
        "(Ctrl-C stops supervision; nodes stay in their states)",
        file=sys.stderr,
        flush=True,
    )
    if args.duration is None:
        await asyncio.Event().wait()  # until Ctrl-C or SIGTERM
    else:
        await asyncio.sleep(args.duration)
    return _EXIT_OK

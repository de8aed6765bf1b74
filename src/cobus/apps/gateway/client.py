"""A client of a CiA 309-3 gateway (cobus's or any other): send request lines, get each
one's reply as data (``cobus gw``).

Requests without a sequence number get one; a reply is every line up to the one with the
request's number (``help`` answers with several). Both dialects' error lines are read:
``[1] ERROR:101 #text`` (CANopenNode) and ``[1] ERROR: 101 (text)`` (Lely).
"""

from __future__ import annotations

import re
import socket
from dataclasses import dataclass, field

__all__ = ["GatewayClient", "Reply", "TokenRefused", "error_class", "reply_of"]


class TokenRefused(Exception):
    """The gateway did not take the client's token."""


_SEQ = re.compile(r"\s*\[\s*([0-9]+)\s*\]\s?(.*)\Z", re.S)
_EVENT = re.compile(r"[0-9]+ (pdo [0-9]|[0-9]+ (BOOT_UP|EMCY|ERROR|USER|SDO))")
_ERROR = re.compile(
    r"ERROR:\s*(0x[0-9A-Fa-f]{8}|[0-9A-Fa-f]{8}(?=\s*\()|[0-9]+)\s*(?:#\s*(.*)|\((.*)\))?\Z"
)


@dataclass
class Reply:
    """The gateway's answer to one request: ``ok`` with ``value`` (None for a plain OK), or
    the error ``code`` (an SDO abort code when above 0xFFFF) and its ``text``."""

    request: str
    ok: bool
    value: str | None = None
    code: int | None = None
    text: str = ""
    #: Lines that came before the closing one (help's text).
    lines: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        """The reply for ``--json``."""
        out: dict[str, object] = {"request": self.request, "ok": self.ok}
        if self.ok:
            out["value"] = self.value
            if self.lines:
                out["lines"] = self.lines
        else:
            shown = f"0x{self.code:08X}" if (self.code or 0) > 0xFFFF else self.code
            out.update(error=shown, text=self.text, kind=error_class(self.code))
        return out


def error_class(code: int | None) -> str:
    """What kind of error ``code`` is: "abort" (the device refused by an SDO abort),
    "timeout" (no answer), "syntax" (the request was wrong) or "refused" (the gateway
    would not do it)."""
    if code is None:
        return "refused"
    if code == 0x05040000 or code == 103:
        return "timeout"
    if code > 0xFFFF:
        return "abort"
    if code == 101:
        return "syntax"
    return "refused"


class GatewayClient:
    """A connection to the gateway at ``host``:``port`` (or on the Unix socket ``unix``);
    ``timeout`` seconds per reply. With a ``token``, it gives it (``auth``) when the gateway
    first asks for it (a request refused until ``auth TOKEN``; that request is then sent
    again): a gateway that asks for none never sees it. :class:`TokenRefused` when the
    gateway does not take it."""

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = 5000,
        timeout: float = 30.0,
        *,
        unix: str | None = None,
        token: str | None = None,
    ) -> None:
        if unix is not None:
            self._sock = socket.socket(socket.AF_UNIX)
            self._sock.settimeout(timeout)
            try:
                self._sock.connect(unix)
            except OSError:
                self._sock.close()
                raise
        else:
            self._sock = socket.create_connection((host, port), timeout=timeout)
        self._file = self._sock.makefile("rb")
        self._seq = 0
        #: Unsolicited lines (``1 5 BOOT_UP``, ``1 5 EMCY ...``) that came so far, oldest
        #: first; whoever reads them empties the list.
        self.events: list[str] = []
        self._token = token

    def close(self) -> None:
        """End the connection."""
        self._file.close()
        self._sock.close()

    def __enter__(self) -> GatewayClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def request(self, line: str) -> Reply:
        """Send ``line`` (a number is put in front unless it has one) and read its reply."""
        reply = self._request(line)
        if (
            self._token is not None
            and not reply.ok
            and reply.code == 102
            and "auth TOKEN" in reply.text
        ):
            token, self._token = self._token, None  # (given once)
            given = self._request(f"auth {token}")
            if not given.ok:
                raise TokenRefused(f"the gateway refused the token: {given.text}")
            reply = self._request(line)
        return reply

    def _request(self, line: str) -> Reply:
        text = line.strip()
        match = _SEQ.match(text)
        if match:
            seq = int(match.group(1))
        else:
            self._seq += 1
            seq = self._seq
            text = f"[{seq}] {text}"
        self._sock.sendall(text.encode("utf-8") + b"\n")
        before: list[str] = []
        while True:
            raw = self._file.readline()
            if not raw:
                raise ConnectionError("the gateway closed the connection before it answered")
            got = raw.decode("utf-8", "replace").rstrip("\r\n")
            answer = _SEQ.match(got)
            if answer is None and _EVENT.match(got):
                self.events.append(got)  # (an unsolicited line: no part of any reply)
                continue
            if answer is None:
                if got.lstrip().startswith("ERROR"):  # (a line the gateway could not number)
                    return _reply(line.strip(), got.strip(), before)
                before.append(got)
                continue
            if int(answer.group(1)) == seq:
                return _reply(line.strip(), answer.group(2), before)
            before.append(got)


def reply_of(request: str, lines: list[str]) -> Reply:
    """The :class:`Reply` a gateway's answer ``lines`` to ``request`` make (the last line
    closes it, ``[seq]`` or not; the lines before it are help's text)."""
    if not lines:
        return Reply(request, False, code=102, text="no answer")
    match = _SEQ.match(lines[-1])
    body = match.group(2) if match else lines[-1]
    return _reply(request, body, lines[:-1])


def _reply(request: str, body: str, before: list[str]) -> Reply:
    error = _ERROR.match(body.strip())
    if error is None:
        value = None if body.strip() == "OK" else body
        return Reply(request, True, value, lines=before)
    number, hash_text, paren_text = error.groups()
    hexadecimal = number.lower().startswith("0x") or len(number) == 8  # (Lely: no 0x)
    code = int(number, 16) if hexadecimal else int(number)
    return Reply(request, False, code=code, text=(hash_text or paren_text or "").strip())

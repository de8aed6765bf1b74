"""Blocking twins generated from the async classes, so the two surfaces cannot drift apart.

A subclass of :class:`BlockingTwin` declared with ``twin_of=`` gets the async class's public
names: a coroutine method becomes a method that runs it on the network's loop and waits for
it; a plain method, a property or an annotated public attribute is run or read on the loop
thread, except an attribute annotated ``Final`` (set once in ``__init__``, never again): that
one is read in the calling thread the first time and kept, so ``node.sdo.upload(...)`` costs
no trip to the loop for ``node.sdo``; a callback given to an
``add_*callback``/``add_*listener`` method runs in the blocking network's callback thread
(inline on the simulated clock). What a call returns is wrapped in its own twin when its
class has one, so ``node.tpdo[1]`` of a blocking node is a blocking PDO.
"""

from __future__ import annotations

import functools
import inspect
import re
import sys
import weakref
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from cobus.runtime.blocking import Runner

__all__ = ["BlockingTwin", "public_names", "runner_of", "twin_of"]

_TWINS: dict[type, type[BlockingTwin]] = {}
_CALLBACKS: weakref.WeakKeyDictionary[Any, dict[Callable[..., object], Callable[..., None]]] = (
    weakref.WeakKeyDictionary()
)


def _registers_callback(name: str) -> bool:
    """``add_callback``, ``add_listener``, ``add_tpdo_listener``...: the first argument is a
    user callback, run in the blocking network's callback thread."""
    return name.startswith("add_") and name.endswith(("callback", "listener"))


def _unregisters_callback(name: str) -> bool:
    return name.startswith("remove_") and name.endswith(("callback", "listener"))


_CONTAINER = ("__getitem__", "__setitem__", "__iter__", "__len__", "__contains__")


class BlockingTwin:
    """Base of the generated blocking twins: ``aio`` is the async object behind it.

    ``class RemoteNmt(BlockingTwin, twin_of=AsyncRemoteNmt)`` gets every public member of the
    async class (see the module docstring) that its body does not define itself; annotations
    in the body type the sub-services for static checkers.
    """

    __twin_of__: type
    #: Public names of the async class that mean nothing to blocking code (the steps of a
    #: transfer the twin's own methods take): the twin does not offer them.
    _async_only: frozenset[str] = frozenset()

    def __init_subclass__(cls, twin_of: type | None = None, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if twin_of is not None:
            _fill(cls, twin_of)

    #: Given as an argument to a twin's method, the async object behind it is passed on.
    _twin_unwrap = True

    if TYPE_CHECKING:  # generated members are invisible to static checkers: typed as Any

        def __getattr__(self, name: str) -> Any: ...
        def __setattr__(self, name: str, value: Any) -> None: ...
        def __getitem__(self, key: Any) -> Any: ...
        def __setitem__(self, key: Any, value: Any) -> None: ...
        def __iter__(self) -> Iterator[Any]: ...
        def __len__(self) -> int: ...
        def __contains__(self, key: object) -> bool: ...

    else:

        def __setattr__(self, name: str, value: Any) -> None:
            if isinstance(getattr(type(self), name, None), _Fixed):
                raise AttributeError(f"{name!r} is fixed when the object is made: it cannot be set")
            object.__setattr__(self, name, value)

        def __getattr__(self, name: str) -> Any:
            """What a subclass of the async class adds (``rig.device(9)`` is an I/O module
            with its own methods): forwarded like the generated members."""
            if name.startswith("_"):
                raise AttributeError(name)
            if name in self._async_only:
                raise AttributeError(
                    f"{type(self).__name__}.{name} is for async code (the step of a transfer "
                    "that the blocking methods take themselves)"
                )
            value = self._runner.call(getattr, self.aio, name)
            if inspect.iscoroutinefunction(value):
                return lambda *a, **k: self._wrap(self._runner.run(value(*_in(a), **_kin(k))))
            if callable(value) and inspect.ismethod(value):
                return lambda *a, **k: self._wrap(
                    self._runner.call(lambda: value(*_in(a), **_kin(k)))
                )
            return self._wrap(value)

    def __init__(self, aio: Any, runner: Runner) -> None:
        self.aio = aio
        self._runner = runner
        # the twins handed out, while their users hold them (an object gives the same twin)
        self._children: weakref.WeakValueDictionary[int, BlockingTwin] = (
            weakref.WeakValueDictionary()
        )

    def _wrap(self, value: Any) -> Any:
        if isinstance(value, list | tuple) and value and twin_of(type(value[0])) is not None:
            return type(value)(self._wrap(item) for item in value)
        twin = twin_of(type(value))
        if twin is None:
            return value
        known = self._children.get(id(value))
        if known is not None and known.aio is value:
            return known
        made = twin(value, self._runner)
        self._children[id(value)] = made
        return made

    def _callbacks(self) -> dict[Callable[..., object], Callable[..., None]]:
        """User callbacks and their wrapped forms, kept with the async object (any twin of
        it can take a callback back)."""
        try:
            table = _CALLBACKS.get(self.aio)
            if table is None:
                table = _CALLBACKS[self.aio] = {}
        except TypeError:  # an object without weak references: kept with this twin
            table = self.__dict__.setdefault("_own_callbacks", {})
        return table

    def __repr__(self) -> str:
        return repr(self.aio)


def _unwrap(value: Any) -> Any:
    """The async object behind a twin or a blocking network given as an argument."""
    return value.aio if getattr(type(value), "_twin_unwrap", False) else value


def _in(args: tuple[Any, ...]) -> list[Any]:
    return [_unwrap(a) for a in args]


def _kin(kwargs: dict[str, Any]) -> dict[str, Any]:
    return {k: _unwrap(v) for k, v in kwargs.items()}


def runner_of(network: Any) -> Runner:
    """The runner of a blocking :class:`~cobus.runtime.Network`: what a twin made for an
    object on its loop is given (outside the runtime, instead of its private name)."""
    runner: Runner = network._runner
    return runner


def twin_of(cls: type) -> type[BlockingTwin] | None:
    """The blocking twin of ``cls`` (or of its nearest base that has one)."""
    for klass in cls.__mro__:
        twin = _TWINS.get(klass)
        if twin is not None:
            return twin
    return None


def public_names(cls: type) -> set[str]:
    """The public surface of a class: methods, properties and annotated attributes, with the
    container protocol it supports."""
    names: set[str] = set()
    for klass in cls.__mro__:
        if klass in (object, BlockingTwin):
            continue
        names.update(n for n in vars(klass) if not n.startswith("_") or n in _CONTAINER)
        names.update(n for n in vars(klass).get("__annotations__", {}) if not n.startswith("_"))
    return names


def _member(cls: type, name: str) -> Any:
    for klass in cls.__mro__:
        if name in vars(klass):
            return vars(klass)[name]
    return None


def _coroutine(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    @functools.wraps(fn)
    def method(self: BlockingTwin, *args: Any, **kwargs: Any) -> Any:
        coro = getattr(self.aio, name)(*_in(args), **_kin(kwargs))
        return self._wrap(self._runner.run(coro))

    return method


def _plain(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
    if _registers_callback(name):

        @functools.wraps(fn)
        def add(self: BlockingTwin, callback: Callable[..., object], *args: Any) -> Any:
            wrapped = self._runner.callback(callback)
            self._callbacks()[callback] = wrapped
            return self._runner.call(getattr(self.aio, name), wrapped, *_in(args))

        return add
    if _unregisters_callback(name):

        @functools.wraps(fn)
        def remove(self: BlockingTwin, callback: Callable[..., object]) -> Any:
            wrapped = self._callbacks().pop(callback, callback)
            return self._runner.call(getattr(self.aio, name), wrapped)

        return remove

    @functools.wraps(fn)
    def method(self: BlockingTwin, *args: Any, **kwargs: Any) -> Any:
        bound = getattr(self.aio, name)
        return self._wrap(self._runner.call(lambda: bound(*_in(args), **_kin(kwargs))))

    return method


def _property(name: str, doc: str | None, settable: bool) -> property:
    def get(self: BlockingTwin) -> Any:
        # on the loop thread: a property may compute from state the loop is changing
        return self._wrap(self._runner.call(getattr, self.aio, name))

    def put(self: BlockingTwin, value: Any) -> None:
        self._runner.call(setattr, self.aio, name, value)

    return property(get, put if settable else None, doc=doc)


class _Fixed:
    """A ``Final`` attribute of the async object: read in the calling thread on first use
    (it was set in the object's ``__init__``, before the object was handed out, and never
    changes) and kept, in its twin, in the twin's own ``__dict__`` under the same name.
    Later reads find it there, a plain attribute: this descriptor defines no ``__set__``,
    and :meth:`BlockingTwin.__setattr__` refuses an assignment."""

    def __init__(self, name: str, doc: str | None) -> None:
        self._name = name
        self.__doc__ = doc

    def __get__(self, twin: BlockingTwin | None, owner: type | None = None) -> Any:
        if twin is None:
            return self
        made = twin._wrap(getattr(twin.aio, self._name))
        return twin.__dict__.setdefault(self._name, made)  # a race keeps the first


_FINAL = re.compile(r"^(typing\.)?Final\b")


def _iterate(self: BlockingTwin) -> Iterator[Any]:
    items: list[Any] = self._runner.call(list, self.aio)
    return iter([self._wrap(item) for item in items])


def _getitem(self: BlockingTwin, key: Any) -> Any:
    return self._wrap(self._runner.call(self.aio.__getitem__, key))


def _setitem(self: BlockingTwin, key: Any, value: Any) -> None:
    self._runner.call(self.aio.__setitem__, key, value)


def _len(self: BlockingTwin) -> int:
    result: int = self._runner.call(len, self.aio)
    return result


def _contains(self: BlockingTwin, key: object) -> bool:
    result: bool = self._runner.call(lambda: key in self.aio)
    return result


_PROTOCOL: dict[str, Callable[..., Any]] = {
    "__getitem__": _getitem,
    "__setitem__": _setitem,
    "__iter__": _iterate,
    "__len__": _len,
    "__contains__": _contains,
}


_DOC_COMMENT = re.compile(r"^\s*#: ?(.*)$")
_ANNOTATION = re.compile(r"^\s*([A-Za-z_]\w*)\s*:")


@functools.cache
def _source_lines(path: str) -> tuple[str, ...]:
    try:
        with open(path, encoding="utf-8") as fh:
            return tuple(fh.read().splitlines())
    except (OSError, UnicodeDecodeError):
        return ()


def _class_lines(cls: type) -> list[str]:
    """The lines of ``cls``'s body, found in its module's file by a plain scan: where
    ``inspect.getsource`` parses the whole module for each class (~5 ms each, 60 ms of
    every command's start)."""
    path = getattr(sys.modules.get(cls.__module__), "__file__", None)
    if not path:
        return []
    lines = _source_lines(path)
    head = re.compile(rf"(\s*)class {re.escape(cls.__name__)}\b")
    for number, line in enumerate(lines):
        match = head.match(line)
        if match is None:
            continue
        indent = len(match.group(1))
        body = [line]
        for following in lines[number + 1 :]:
            stripped = following.lstrip()
            if stripped and len(following) - len(stripped) <= indent and stripped[0] not in "#)":
                break
            body.append(following)
        return body
    return []


def _attribute_docs(cls: type) -> dict[str, str]:
    """The ``#:`` comments above a class's annotated attributes, as their docs."""
    lines = _class_lines(cls)
    docs: dict[str, str] = {}
    pending: list[str] = []
    for line in lines:
        comment = _DOC_COMMENT.match(line)
        if comment:
            pending.append(comment.group(1))
            continue
        annotation = _ANNOTATION.match(line)
        if annotation and pending:
            docs.setdefault(annotation.group(1), " ".join(pending))
        pending = []
    return docs


def _fill(twin: type[BlockingTwin], async_cls: type) -> None:
    twin.__twin_of__ = async_cls
    annotated: dict[str, object] = {}
    docs: dict[str, str] = {}
    for klass in reversed(async_cls.__mro__):
        annotated.update(vars(klass).get("__annotations__", {}))
        docs.update(_attribute_docs(klass))
    for attr in sorted(public_names(async_cls)):
        if attr in vars(twin):
            continue  # written out in the twin's body: it knows better
        if attr in twin._async_only:
            continue
        member = _member(async_cls, attr)
        if attr in _PROTOCOL:
            made: Any = _PROTOCOL[attr]
        elif isinstance(member, property):
            made = _property(attr, member.__doc__, member.fset is not None)
        elif inspect.iscoroutinefunction(member):
            made = _coroutine(attr, member)
        elif inspect.isfunction(member):
            made = _plain(attr, member)
        elif attr in annotated:
            doc = docs.get(attr) or f"``{async_cls.__name__}.{attr}`` of the async object."
            if _FINAL.match(str(annotated[attr])):
                made = _Fixed(attr, doc)
            else:
                made = _property(attr, doc, True)
        else:  # a class constant
            made = member
        setattr(twin, attr, made)
    _TWINS[async_cls] = twin

"""A world in Python: listen on the link, serve one rig at a time, step a scene.

Why it exists: a lab writes its experiment as a small Python class (what the hands touch, what
happens when they push) and `spidar run --world ADDR` feels it through the same 1 kHz loop,
safety rules and tension allocation as the built-in worlds. The rules this end keeps are the
Rust world's (`link/src/world.rs`, `docs/link.md`):

- a rig is served after a valid ``Hello``: the same protocol version, sizes, a usable period,
  and the scene this world runs (or none asked for); anything else gets a ``Refuse`` naming
  both sides. A hello of another protocol version is answered in this version, so the rig names
  both versions;
- while a rig is served, hellos from other addresses are refused (busy) and other datagrams
  from elsewhere are dropped and counted;
- every queued datagram is drained before a step, so no sample is lost to a slow step;
- a step is due when a sample's rig time reaches the next step's time (every ``step_s`` of the
  rig's clock); the model is stamped with that sample's time, which is never later than the
  rig's now. On a virtual-clock rig (`spidar run --virtual --world ADDR`, which waits for the
  world's model whenever one is due) this is the Rust world's lockstep rule, so a Python world
  is run there as exactly as a Rust one;
- a rig that says ``Bye``, is silent for ``rig_lost_s`` or whose socket is gone is lost: the
  scene pauses until a rig connects; the scene's time never jumps back;
- leaving on purpose (Ctrl-C, SIGTERM, the time asked for) says ``Bye``.

What it must never do: send a malformed datagram, wait on the rig, or keep serving a rig it has
lost. What the models say is the world's business: the rig clamps, fades and counts whatever
arrives (NaN, huge stiffness, a flood of models), so a scene's mistake changes nothing beyond the
rig's own guards.
"""

from __future__ import annotations

import errno
import os
import random
import signal
import socket
import stat
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Callable, Iterable, List, Optional, Sequence, Tuple, Union

from . import wire
from .wire import (
    HANDS,
    MAX_PROXIES,
    STRINGS,
    Bye,
    ContactModel,
    HandContact,
    HandSample,
    Hello,
    Proxy,
    Refuse,
    RigInfo,
    RigStatus,
    Vec3,
    Welcome,
    WireError,
)

#: What a scene's step may return: a whole model, or just its proxies.
StepResult = Union[ContactModel, Sequence[Proxy], None]


class LinkAddressError(ValueError):
    """An address that is not ``unix:PATH`` or ``udp://HOST:PORT``."""


class World:
    """A scene behind the link. Subclass it and write :meth:`step`.

    - ``name``: the scene's name as a rig may ask for it (``spidar run --scene NAME``);
    - ``step_s``: rig time between two models (the built-in worlds step every 3 ms);
    - :meth:`on_connect` is told the rig's geometry (world frame) when a rig is served;
    - :meth:`step` gets the rig's time and every sample since the last step, and returns the
      contact model (or its proxies).
    """

    name: str = "python"
    step_s: float = 0.003

    def on_connect(self, rig: RigInfo) -> None:
        """A rig is served (again): its period, anchors, home points, limits (world frame)."""

    def on_rig_lost(self, why: str) -> None:
        """The rig left or went silent: the scene is paused until a rig connects."""

    def step(self, t_s: float, samples: List[HandSample]) -> StepResult:
        """One step at rig time ``t_s`` (the newest sample's ``t_s``) with every sample since the
        last step (oldest first); returns what the hands touch now."""
        raise NotImplementedError("a World's step(t_s, samples) returns its contact model or proxies")


@dataclass
class Stats:
    """Counts of this end of the link (the Rust world's `WorldStats`)."""

    connections: int = 0
    steps: int = 0
    samples: int = 0
    #: Samples that never arrived (gaps in their tick numbers).
    samples_lost: int = 0
    samples_out_of_order: int = 0
    statuses: int = 0
    models_sent: int = 0
    #: Models the rig's full queue did not take.
    models_dropped: int = 0
    malformed: int = 0
    wrong_version: int = 0
    foreign: int = 0
    unexpected: int = 0
    refusals: int = 0
    pauses: int = 0
    #: What was said, one line per event (connections, refusals, losses).
    events: List[str] = field(default_factory=list)


def parse_address(text: str) -> Tuple[int, object]:
    """``unix:PATH`` -> (AF_UNIX, path); ``udp://HOST:PORT`` -> (AF_INET, (host, port));
    ``udp://:PORT`` is 127.0.0.1 (as the Rust side)."""
    if text.startswith("unix:") and len(text) > 5:
        return socket.AF_UNIX, text[5:]
    if text.startswith("udp://"):
        host, _, port = text[6:].rpartition(":")
        if port.isdigit() and int(port) < 65536:
            return socket.AF_INET, (host or "127.0.0.1", int(port))
    raise LinkAddressError(
        f"'{text}' is not a link address: use unix:PATH (a world on this machine) or udp://HOST:PORT "
        "(udp://:PORT means 127.0.0.1)"
    )


def default_address() -> str:
    """Where ``spidar world`` listens by default: ``$XDG_RUNTIME_DIR/spidar/world.sock``, or a
    new private directory."""
    run = os.environ.get("XDG_RUNTIME_DIR")
    if run and os.path.isdir(run):
        return f"unix:{os.path.join(run, 'spidar', 'python-world.sock')}"
    return f"unix:{os.path.join(tempfile.mkdtemp(prefix='spidar-python-'), 'world.sock')}"


def _prepare_unix_path(path: str) -> None:
    """The socket's directory is made private (0700) if new and must be the user's alone; an
    existing path is replaced only when it is a stale socket of the user's."""
    d = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.exists(d):
        os.makedirs(d, mode=0o700)
    st = os.lstat(d)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid() or st.st_mode & 0o022:
        raise PermissionError(
            f"directory {d} is not a directory of this user that no one else can write to: "
            "choose a socket path in a private directory"
        )
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode) or st.st_uid != os.getuid():
        raise FileExistsError(f"{path} exists and is not a socket of this user: choose another path")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    try:
        probe.connect(path)
        raise FileExistsError(f"{path}: a process still listens there: stop it or choose another path")
    except ConnectionRefusedError:
        os.unlink(path)  # stale: its process is gone
    finally:
        probe.close()


class Link:
    """The world's socket (Unix datagram or UDP) and the rules of the link. Used by
    :func:`serve`; usable alone for tests that need to speak the link by hand."""

    def __init__(self, address: str, scene: str, step_s: float, rig_lost_s: float = 0.5):
        self.family, self.where = parse_address(address)
        self.scene = scene
        self.step_s = step_s
        self.rig_lost_s = rig_lost_s
        self.sock = socket.socket(self.family, socket.SOCK_DGRAM)
        if self.family == socket.AF_UNIX:
            _prepare_unix_path(str(self.where))
        self.sock.bind(self.where)
        if self.family == socket.AF_UNIX:
            self.address = f"unix:{self.where}"
        else:
            host, port = self.sock.getsockname()[:2]
            self.address = f"udp://{host}:{port}"
        self.sock.setblocking(False)
        try:  # a few seconds of samples, so a world that stalls loses none (best effort)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
        except OSError:
            pass
        self.session = random.getrandbits(64)
        self.seq = 0
        self.stats = Stats()
        self.peer: Optional[object] = None
        self.peer_session: Optional[int] = None
        self.rig: Optional[RigInfo] = None
        self.status: Optional[RigStatus] = None
        self.last_heard = 0.0
        self.last_seq = 0
        self.last_tick: Optional[int] = None
        self._last_refusal: Optional[Tuple[int, str]] = None
        self._said_version: Optional[int] = None
        #: Protocol version written into this end's datagrams (tests of a mismatch change it).
        self.version = wire.PROTOCOL_VERSION

    def close(self, say_bye: bool = True) -> None:
        """Says goodbye to the served rig (if any) and closes the socket."""
        if say_bye and self.peer is not None:
            self._send(Bye(self.session), self.peer)
        self.peer = None
        self.sock.close()
        if self.family == socket.AF_UNIX:
            try:
                os.unlink(str(self.where))
            except OSError:
                pass

    def _send(self, m: wire.Message, to: object) -> Optional[OSError]:
        self.seq += 1
        try:
            self.sock.sendto(wire.encode(m, self.seq, self.version), to)
            return None
        except OSError as e:
            return e

    def _say(self, line: str) -> None:
        self.stats.events.append(line)

    def _refuse(self, to: object, session: int, code: int, reason: str) -> None:
        self.stats.refusals += 1
        self._send(Refuse(session, code, reason), to)
        if self._last_refusal != (session, reason):
            self._last_refusal = (session, reason)
            self._say(f"refused a rig at {to}: {reason}")

    def _check_hello(self, h: Hello) -> Optional[Tuple[int, str]]:
        if (h.hands, h.strings, h.max_proxies) != (HANDS, STRINGS, MAX_PROXIES):
            return wire.REFUSE_SHAPE, (
                f"the rig has {h.hands} hands, {h.strings} strings and {h.max_proxies} proxies per model, "
                f"this world {HANDS}, {STRINGS} and {MAX_PROXIES}: build both from the same spidar source"
            )
        if h.scene and h.scene != self.scene:
            return wire.REFUSE_SCENE, (
                f"this world runs scene '{self.scene}', the rig asked for '{h.scene}' (start a world with "
                f"that scene or leave --scene out of the rig's command)"
            )
        p = h.rig.period_s
        if not (p == p and 0.0 < p <= 0.1):
            return wire.REFUSE_RIG, f"the rig's period {p} s is not between 0 and 0.1 s"
        return None

    def _on_hello(self, h: Hello, frm: object) -> Optional[str]:
        if self.peer is not None and frm != self.peer:
            self._refuse(frm, h.rig_session, wire.REFUSE_BUSY,
                         f"this world serves the rig at {self.peer}: stop that rig or start another world")
            return None
        why = self._check_hello(h)
        if why is not None:
            self.peer = None
            self._refuse(frm, h.rig_session, *why)
            return None
        self._send(
            Welcome(h.rig_session, self.session, HANDS, STRINGS, MAX_PROXIES, self.step_s, self.scene), frm
        )
        same = self.peer is not None and self.peer_session == h.rig_session
        if not same:
            self.last_seq, self.last_tick, self.status = 0, None, None
        again = self.peer_session == h.rig_session
        self.stats.connections += 1
        self.peer, self.peer_session, self.rig = frm, h.rig_session, h.rig
        self.last_heard = time.monotonic()
        self._last_refusal = None
        self._say(
            f"rig at {frm} connected again: scene running"
            if again
            else f"rig connected from {frm} (session {h.rig_session:016x}): scene running"
        )
        return "connected"

    def wait(self, timeout_s: float) -> bool:
        """Waits until a datagram is queued or ``timeout_s`` passes."""
        import select

        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        return bool(r)

    def drain(self, samples: List[HandSample]) -> List[str]:
        """Reads every queued datagram: the served rig's samples go to ``samples`` (in order);
        returns what happened ("connected", "left", "lost"). Then checks the rig is alive."""
        happened: List[str] = []
        while True:
            try:
                d, frm = self.sock.recvfrom(wire.MAX_DATAGRAM + 1)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                if e.errno in (errno.ECONNREFUSED, errno.ENOENT):
                    continue  # a send of ours found nobody (UDP reports it on a later call)
                raise
            from_peer = self.peer is not None and frm == self.peer
            try:
                h, m = wire.decode(d)
            except WireError as e:
                if e.version is not None:
                    self.stats.wrong_version += 1
                    reason = f"this world speaks link protocol {wire.PROTOCOL_VERSION}, the rig {e.version}"
                    self._send(Refuse(0, wire.REFUSE_OTHER, reason), frm)
                    if self._said_version != e.version:
                        self._said_version = e.version
                        self._say(
                            f"a rig at {frm} speaks link protocol {e.version}, this world speaks "
                            f"{wire.PROTOCOL_VERSION}: refused (run the same spidar version on both sides)"
                        )
                elif from_peer:
                    self.stats.malformed += 1
                else:
                    self.stats.foreign += 1
                continue
            if isinstance(m, Hello):
                if self._on_hello(m, frm):
                    happened.append("connected")
                continue
            if not from_peer:
                self.stats.foreign += 1
                continue
            if isinstance(m, HandSample):
                self.last_heard = time.monotonic()
                if h.seq <= self.last_seq or (self.last_tick is not None and m.tick <= self.last_tick):
                    self.stats.samples_out_of_order += 1
                    continue
                if self.last_tick is not None:
                    self.stats.samples_lost += m.tick - self.last_tick - 1
                self.last_seq, self.last_tick = h.seq, m.tick
                self.stats.samples += 1
                samples.append(m)
            elif isinstance(m, RigStatus):
                self.last_heard = time.monotonic()
                self.status = m
                self.stats.statuses += 1
            elif isinstance(m, Bye) and m.session == self.peer_session:
                self._say(f"rig at {self.peer} stopped: scene paused, waiting for a rig")
                self.peer = None
                happened.append("left")
            else:
                self.stats.unexpected += 1
        if self.peer is not None:
            silent = time.monotonic() - self.last_heard
            if silent > self.rig_lost_s:
                self._say(f"rig at {self.peer} lost (silent for {silent:.2f} s): scene paused, waiting for a rig")
                self.peer = None
                happened.append("lost")
        return happened

    def send_model(self, m: ContactModel) -> bool:
        """Sends a model to the served rig; False when there is none or it could not take it."""
        if self.peer is None:
            return False
        err = self._send(m, self.peer)
        if err is None:
            self.stats.models_sent += 1
            return True
        if err.errno in (errno.EAGAIN, errno.ENOBUFS):
            self.stats.models_dropped += 1
        elif err.errno in (errno.ECONNREFUSED, errno.ENOENT):
            self._say(f"rig at {self.peer} lost (its socket is gone): scene paused, waiting for a rig")
            self.peer = None
        return False


def as_model(result: StepResult) -> ContactModel:
    """A step's result as a model (proxies alone become a model with nothing else)."""
    if result is None:
        return ContactModel()
    if isinstance(result, ContactModel):
        return result
    return ContactModel(proxies=list(result))


@dataclass
class ServeReport:
    """What :func:`serve` did."""

    address: str
    stats: Stats
    #: Rig time of the last step (s, the scene's own time line).
    scene_t_s: float = 0.0


def serve(
    world: World,
    address: Optional[str] = None,
    *,
    seconds: Optional[float] = None,
    rig_lost_s: float = 0.5,
    on_listening: Optional[Callable[[str], None]] = None,
    say: Optional[Callable[[str], None]] = None,
    stop: Optional[Callable[[], bool]] = None,
) -> ServeReport:
    """Serves ``world`` at ``address`` (``unix:PATH`` or ``udp://HOST:PORT``) until ``stop()``
    says so, SIGINT or SIGTERM arrives, or ``seconds`` of scene time have run.

    ``on_listening`` is told the address once the socket is bound (a UDP port 0 is the port the
    system chose); ``say`` gets one line per event (default: print to stderr).
    """
    say = say or (lambda line: print(f"world: {line}", file=sys.stderr, flush=True))
    link = Link(address or default_address(), world.name, world.step_s, rig_lost_s)
    stopping: List[int] = []

    def on_signal(signum, _frame):
        stopping.append(signum)

    old = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            old[sig] = signal.signal(sig, on_signal)
        except ValueError:
            pass  # not the main thread: stop() decides
    if on_listening:
        on_listening(link.address)
    said = 0
    step_ns = round(world.step_s * 1e9)
    # Scene time = rig time + offset: a rig that connects again (or a new one, whose clock starts
    # at zero) continues the scene one step after where it paused.
    offset_s = 0.0
    last_scene_t: Optional[float] = None
    resume = True
    next_due_ns = 0  # rig time (ns) at which the next step is due
    seq = 0
    samples: List[HandSample] = []
    try:
        while not stopping and not (stop and stop()):
            if seconds is not None and last_scene_t is not None and last_scene_t >= seconds:
                break
            link.wait(0.05)
            arrived: List[HandSample] = []
            for what in link.drain(arrived):
                if what == "connected":
                    resume, next_due_ns = True, 0
                    samples = []
                    if link.rig is not None:
                        world.on_connect(link.rig)
                else:  # left or lost: paused
                    link.stats.pauses += 1
                    samples = []
                    world.on_rig_lost(what)
            for line in link.stats.events[said:]:
                say(line)
            said = len(link.stats.events)
            if link.peer is None or not arrived:
                continue
            if resume:
                first = arrived[0].t_s
                offset_s = 0.0 if last_scene_t is None else last_scene_t + world.step_s - first
                resume = False
            for smp in arrived:
                smp.t_s += offset_s
            samples.extend(arrived)
            # Due when the newest sample's rig time reaches the next step's. On a virtual-clock rig
            # (which waits for the model after each due sample) the due sample is always the newest;
            # in real time a world slower than its step steps once, not in a burst.
            rig_t_s = arrived[-1].t_s - offset_s
            now_ns = round(rig_t_s * 1e9)
            if now_ns < next_due_ns:
                continue
            t_s = arrived[-1].t_s
            model = as_model(world.step(t_s, samples))
            samples = []
            seq += 1
            model.seq = seq
            model.stamp_s = rig_t_s
            link.send_model(model)
            link.stats.steps += 1
            last_scene_t = t_s
            next_due_ns = now_ns + step_ns
        for line in link.stats.events[said:]:
            say(line)
    finally:
        link.close(say_bye=True)
        for sig, h in old.items():
            signal.signal(sig, h)
    return ServeReport(link.address, link.stats, last_scene_t or 0.0)


def main(world: World, argv: Optional[Sequence[str]] = None) -> ServeReport:
    """A command line for a world script: ``--listen ADDR`` (default: a socket in
    ``$XDG_RUNTIME_DIR/spidar/``), ``--seconds S`` (scene time to run, default: until Ctrl-C),
    ``--rig-lost-s S``. Prints the command that connects a rig, and a summary at the end."""
    import argparse

    p = argparse.ArgumentParser(description=(type(world).__doc__ or "").strip().split("\n")[0] or None)
    p.add_argument("--listen", default=None, help="unix:PATH or udp://HOST:PORT (default: a private Unix socket)")
    p.add_argument("--seconds", type=float, default=None, help="scene time to run (default: until Ctrl-C)")
    p.add_argument("--rig-lost-s", type=float, default=0.5, help="a rig silent this long is lost (s)")
    a = p.parse_args(argv)

    def listening(addr: str) -> None:
        print(f"world: scene '{world.name}' listening at {addr}: run `spidar run --world {addr}`", file=sys.stderr,
              flush=True)

    try:
        rep = serve(world, a.listen, seconds=a.seconds, rig_lost_s=a.rig_lost_s, on_listening=listening)
    except (LinkAddressError, OSError) as e:
        print(f"world: {e}", file=sys.stderr)
        raise SystemExit(2)
    s = rep.stats
    print(
        f"world: {s.steps} steps, {s.connections} rig connections, paused {s.pauses} times; samples {s.samples} "
        f"received, {s.samples_lost} ticks missing, {s.samples_out_of_order} out of order; models {s.models_sent} "
        f"sent, {s.models_dropped} dropped; odd datagrams: {s.malformed} malformed, {s.wrong_version} wrong "
        f"version, {s.foreign} foreign, {s.unexpected} unexpected; {s.refusals} refusals",
        file=sys.stderr,
        flush=True,
    )
    return rep

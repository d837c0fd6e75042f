"""Python worlds against the real rig: `spidar run` (simulated rig, rt-loop, safety, link) with a
world written with this package, on the virtual clock (lockstep, deterministic) and the real one.
What a person meets is what is measured: forces are read from the rig's own recording."""

import json
import math
import os
import re
import signal
import socket
import struct
import time

import pytest

import spidar
from spidar import wire

from conftest import EXAMPLES, export, load_example, python_world_process, run_rig

FORCE_LIMIT_N = 4.0  # configs/rig-spidar-h.ron, both hands
STALE_S, FADE_S = 0.03, 0.1  # the rig file's contact_stale_after_s and contact_fade_s
TENSION_MIN_N = None  # read from the rig's hello when needed

FRONT_WALL_RON = (
    '(kind: "walls-scene", version: 1, name: "front wall", step_s: 0.003, planes: [(label: "wall", '
    "point_m: (0.0, 1.10, -0.30), normal: (0.0, 0.0, 1.0), k_n_per_m: 2000.0, d_n_s_per_m: 5.0)], spheres: [])"
)


def _force(row, hand, what="output_n"):
    return tuple(row[f"hands[{hand}].{what}.{c}"] for c in "xyz")


def _pos(row, hand):
    return tuple(row[f"hands[{hand}].pos_m.{c}"] for c in "xyz")


def _norm(v):
    return math.sqrt(sum(c * c for c in v))


def test_the_python_wall_gives_the_force_of_the_rust_walls_scene_within_5_percent(spidar_bin, sock_dir, serve_world):
    """The same wall in Python and in Rust (the walls scene), the same scripted presses: at the same
    hand positions the rig renders the same force."""
    wall = load_example("wall").Wall()
    served = serve_world(wall, f"unix:{sock_dir}/w.sock")
    run_rig(spidar_bin, "--virtual", "--world", served.address, "--script", "tour", "--seconds", 6, "--quiet",
            "--record", sock_dir / "py.mcap")
    report = served.stop()
    assert report.stats.connections == 1 and report.stats.steps > 1900
    (sock_dir / "front.ron").write_text(FRONT_WALL_RON)
    run_rig(spidar_bin, "--virtual", "--scene", sock_dir / "front.ron", "--script", "tour", "--seconds", 6,
            "--quiet", "--record", sock_dir / "rs.mcap")
    py = export(spidar_bin, sock_dir / "py.mcap", sock_dir / "py")["tick"]
    rs = export(spidar_bin, sock_dir / "rs.mcap", sock_dir / "rs")["tick"]
    assert len(py) == len(rs) > 6000
    compared = 0
    for a, b in zip(py, rs):
        for h in (0, 1):
            if _norm([x - y for x, y in zip(_pos(a, h), _pos(b, h))]) > 1e-4:
                continue  # not the same hand position: nothing to compare
            fa, fb = _force(a, h, "rendered_n"), _force(b, h, "rendered_n")
            if _norm(fb) > 0.5:
                compared += 1
                assert _norm([x - y for x, y in zip(fa, fb)]) <= 0.05 * _norm(fb), (a["tick"], h, fa, fb)
            else:
                assert _norm(fa) <= 0.5 + 0.05 * 0.5, (a["tick"], h, fa, fb)
    assert compared > 1000, f"only {compared} hand-ticks pressed the wall"


def test_a_python_world_killed_mid_contact_fades_the_force_to_zero_within_the_fade_time(spidar_bin, sock_dir):
    """Real clock: the wall world is a process of its own, killed (SIGKILL) while a hand presses
    the wall. The rig's recording shows the force fade to zero within the rig's stale + fade time
    after the last model it took, the rig staying active and stopping cleanly."""
    addr = f"unix:{sock_dir}/w.sock"
    log = sock_dir / "world.log"
    world = python_world_process([EXAMPLES / "wall.py", "--listen", addr], log)
    try:
        deadline = time.monotonic() + 20
        while "listening at" not in log.read_text():
            assert time.monotonic() < deadline and world.poll() is None, log.read_text()
            time.sleep(0.05)
        rig = __import__("subprocess").Popen(
            [spidar_bin, "run", "--world", addr, "--script", "tour", "--seconds", "5", "--quiet",
             "--record", str(sock_dir / "kill.mcap")],
            stdout=__import__("subprocess").PIPE, stderr=__import__("subprocess").PIPE, text=True)
        while "rig connected" not in log.read_text():
            assert time.monotonic() < deadline and rig.poll() is None, log.read_text()
            time.sleep(0.01)
        # The tour presses the front wall from about 1.5 s to 3 s of rig time.
        time.sleep(2.3)
        world.send_signal(signal.SIGKILL)
        out, err = rig.communicate(timeout=60)
        assert rig.returncode == 0, out + err
    finally:
        if world.poll() is None:
            world.kill()
        world.wait()
    ch = export(spidar_bin, sock_dir / "kill.mcap", sock_dir / "csv")
    last = ch["contact_model"][-1]
    last_stamp = last["model.stamp_s"]
    ticks = ch["tick"]
    before = [r for r in ticks if last_stamp - 0.2 <= r["t_s"] and r["tick"] <= last["tick"]]
    assert max(_norm(_force(r, h)) for r in before for h in (0, 1)) > 1.0, "the hand was pressing the wall"
    faded = [r for r in ticks if r["t_s"] >= last_stamp + STALE_S + FADE_S + 0.001]
    assert len(faded) > 500, "the rig ran on after its world died"
    for r in faded:
        assert r["gain"] == 0.0, (r["t_s"], r["gain"])
        for h in (0, 1):
            assert _norm(_force(r, h)) < 1e-9, (r["t_s"], h, _force(r, h))
    assert all(r["state"] == "active" for r in faded[:400]), "the rig stays active, strings held"
    assert "lost 1 times" in out, out


class Hostile:
    """Serves a rig by hand (the package's Link) and sends it every kind of nonsense, one datagram
    a step in turn (a virtual-clock rig waits for one whenever a step is due): a model stamped NaN,
    one with NaN geometry, a wall of 1e12 N/m, garbage. With ``flood`` (for a real-clock rig, which
    never waits: a flood would break a lockstep) also 20 garbage datagrams before each."""

    def __init__(self, address, flood=False):
        self.link = spidar.Link(address, "hostile", 0.003)
        self.sent = {"garbage": 0, "nan_stamp": 0, "models": 0}
        self.stop = False
        self.flood = flood

    def run(self):
        step = 0
        next_due_ns = 0
        while not self.stop:
            self.link.wait(0.05)
            samples = []
            if "connected" in self.link.drain(samples):
                next_due_ns = 0
            for smp in samples:
                now_ns = round(smp.t_s * 1e9)
                if self.link.peer is None or now_ns < next_due_ns:
                    continue
                next_due_ns = now_ns + 3_000_000
                step += 1
                self.send(smp.t_s, step)
        self.link.close()

    def garbage(self):
        if self.link.peer is None:
            return
        self.link.seq += 1
        try:
            self.link.sock.sendto(b"SPDR" + struct.pack("<HBB", wire.PROTOCOL_VERSION, 6, 0) + b"garbage" + os.urandom(20), self.link.peer)
            self.sent["garbage"] += 1
        except OSError:
            pass  # the rig's queue is full: not sent, not counted

    def send(self, t, step):
        if self.flood:
            for _ in range(20):
                self.garbage()
        wall = wire.Plane((0.0, 1.10, -0.30), (0.0, 0.0, 1.0))
        kind = step % 4
        if kind == 3:
            return self.garbage()
        m = [
            wire.ContactModel(stamp_s=math.nan, proxies=[wire.Proxy(wall, 2000.0)]),
            wire.ContactModel(stamp_s=t, proxies=[wire.Proxy(wire.Sphere((math.nan, 1.1, -0.2), 0.1), 1000.0)]),
            wire.ContactModel(stamp_s=t, proxies=[wire.Proxy(wall, 1e12, 5.0)]),
        ][kind]
        m.seq = step
        if self.link.send_model(m):
            self.sent["models"] += 1
            self.sent["nan_stamp"] += kind == 0


def test_nan_huge_stiffness_and_a_flood_change_nothing_beyond_the_clamps_and_are_counted(spidar_bin, sock_dir):
    import threading

    h = Hostile(f"unix:{sock_dir}/h.sock")
    t = threading.Thread(target=h.run, daemon=True)
    t.start()
    try:
        p = run_rig(spidar_bin, "--virtual", "--world", h.link.address, "--script", "tour", "--seconds", 5, "--json",
                    "--quiet")
    finally:
        h.stop = True
        t.join(10)
    j = json.loads(p.stdout)
    assert j["end"]["state"] == "inactive" and j["end"]["clean_stop"], j["end"]
    assert j["safety"]["faults"] == 0
    assert max(j["forces"]["max_force_n"]) <= FORCE_LIMIT_N + 1e-9, j["forces"]
    assert sum(j["safety"]["clamped_ticks"]) > 100, "the 1e12 N/m wall is clamped to the force limit"
    assert sum(j["safety"]["stiffness_limited_ticks"]) > 100, "and its stiffness limited"
    link = j["link"]
    # Every datagram is counted, but for the last few still on their way when the rig stopped.
    in_flight = 3
    assert h.sent["garbage"] - in_flight <= link["malformed"] <= h.sent["garbage"], (link, h.sent)
    assert h.sent["nan_stamp"] - in_flight <= link["bad_stamps"] <= h.sent["nan_stamp"], (link, h.sent)
    assert h.sent["models"] - in_flight <= link["models"] <= h.sent["models"], (link, h.sent)
    assert h.sent["garbage"] > 300 and h.sent["nan_stamp"] > 300, h.sent


def test_a_flood_from_the_world_on_the_real_clock_changes_nothing_beyond_the_clamps(spidar_bin, sock_dir):
    """The same nonsense with 20 garbage datagrams before each model (as many as the rig's queue
    takes), against the real-clock loop: no fault, the force within the limit, a clean stop."""
    import threading

    h = Hostile(f"unix:{sock_dir}/f.sock", flood=True)
    t = threading.Thread(target=h.run, daemon=True)
    t.start()
    try:
        p = run_rig(spidar_bin, "--world", h.link.address, "--script", "tour", "--seconds", 3, "--json", "--quiet")
    finally:
        h.stop = True
        t.join(10)
    j = json.loads(p.stdout)
    assert j["end"]["state"] == "inactive" and j["end"]["clean_stop"], j["end"]
    assert j["safety"]["faults"] == 0
    assert max(j["forces"]["max_force_n"]) <= FORCE_LIMIT_N + 1e-9, j["forces"]
    # The flood fills the rig's queue (a Unix socket queues 10 datagrams): most of the world's own
    # models find no room, so its model goes stale and fades, counted; nothing else changes.
    assert h.sent["garbage"] > 5000, h.sent
    assert j["safety"]["stale_model_ticks"] > 0, j["safety"]
    assert j["forces"]["tension_n"]["min"] > 0.0, "strings never slack while active"


def test_the_handshake_refuses_another_protocol_version_naming_both(spidar_bin, sock_dir):
    """A world of another protocol version (this package told it speaks 2): the rig stops at the
    start with both versions named, and the world names both too."""
    addr = f"unix:{sock_dir}/v2.sock"
    log = sock_dir / "v2.log"
    code = ("import spidar, spidar.wire as w; w.PROTOCOL_VERSION = 2; import sys; "
            "sys.argv[0] = 'v2'; exec(open(sys.argv[1]).read().replace('spidar.main(Wall())', 'spidar.main(Wall(), sys.argv[2:])'))")
    world = python_world_process(["-c", code, EXAMPLES / "wall.py", "--listen", addr, "--seconds", "30"], log)
    try:
        deadline = time.monotonic() + 20
        while "listening at" not in log.read_text():
            assert time.monotonic() < deadline and world.poll() is None, log.read_text()
            time.sleep(0.05)
        p = run_rig(spidar_bin, "--virtual", "--world", addr, "--seconds", 1, "--world-timeout-s", 5, check=False)
    finally:
        world.send_signal(signal.SIGTERM)
        world.wait(10)
    assert p.returncode != 0
    assert f"speaks link protocol 2, this rig speaks {wire.PROTOCOL_VERSION}" in p.stderr, p.stderr
    assert f"speaks link protocol {wire.PROTOCOL_VERSION}, this world speaks 2" in log.read_text(), log.read_text()


def test_a_python_world_refuses_a_rig_of_another_version_in_its_own(sock_dir):
    link = spidar.Link(f"unix:{sock_dir}/w.sock", "wall", 0.003)
    rig = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    rig.bind(str(sock_dir / "rig.sock"))
    try:
        rig.sendto(wire.encode(wire.Hello(rig_session=1), 1, version=2), str(sock_dir / "w.sock"))
        link.wait(1.0)
        link.drain([])
        rig.settimeout(2.0)
        h, m = wire.decode(rig.recv(4096))
        assert h.version == wire.PROTOCOL_VERSION and isinstance(m, wire.Refuse)
        assert m.reason == f"this world speaks link protocol {wire.PROTOCOL_VERSION}, the rig 2"
        assert link.stats.wrong_version == 1 and link.peer is None
        # A rig asking for another scene is refused naming both scenes.
        rig.sendto(wire.encode(wire.Hello(rig_session=2, scene="crowd"), 2), str(sock_dir / "w.sock"))
        link.wait(1.0)
        link.drain([])
        _, m = wire.decode(rig.recv(4096))
        assert m.code == wire.REFUSE_SCENE and "runs scene 'wall', the rig asked for 'crowd'" in m.reason
    finally:
        rig.close()
        link.close()


# ---------------------------------------------------------------------------------------------
# The examples, each against the rig on the virtual clock.

BALL_PUSH_SCRIPT = """(kind: "script", version: 1, hands: (
    (segments: [Hold(at_m: (-0.15, 0.0, 0.0), for_s: 100.0)], repeat: false),
    (segments: [
        Hold(at_m: (0.15, 0.0, 0.0), for_s: 0.5),
        Reach(to_m: (0.15, -0.14, -0.03), duration_s: 1.0),
        Reach(to_m: (0.15, -0.14, -0.30), duration_s: 0.5),
        Reach(to_m: (0.15, -0.10, 0.0), duration_s: 0.6),
    ], repeat: false),
))"""


def test_the_ball_example_rolls_away_when_pushed(spidar_bin, sock_dir, serve_world):
    ball = load_example("ball").Ball()
    start_z = ball.pos_m[2]
    (sock_dir / "push.ron").write_text(BALL_PUSH_SCRIPT)
    served = serve_world(ball, f"unix:{sock_dir}/b.sock")
    run_rig(spidar_bin, "--virtual", "--world", served.address, "--script", sock_dir / "push.ron", "--seconds", 4,
            "--quiet")
    served.stop()
    assert ball.pushed_n_s > 0.05, "the hand pushed the ball"
    assert ball.pos_m[2] < start_z - 0.10, f"the ball rolled forward (-z): from {start_z} to {ball.pos_m[2]}"
    assert abs(ball.pos_m[0] - 0.15) < 0.05 and ball.pos_m[1] == pytest.approx(0.96)


def test_the_spring_example_pulls_the_hand_toward_its_point_with_k_times_distance(spidar_bin, sock_dir, serve_world):
    spring = load_example("spring").Spring()
    served = serve_world(spring, f"unix:{sock_dir}/s.sock")
    run_rig(spidar_bin, "--virtual", "--world", served.address, "--script", "hold", "--seconds", 4, "--quiet")
    served.stop()
    t, pos, f = spring.log[-400]  # settled, before the ramp-out at the end
    a = spring.anchor_m
    want = [spring.k_n_per_m * (ai - pi) for ai, pi in zip(a, pos)]
    assert _norm([x - y for x, y in zip(f, want)]) < 0.05 * _norm(want), (f, want)
    home_to_anchor = _norm([0.0, 0.03, -0.05])
    assert _norm([ai - pi for ai, pi in zip(a, pos)]) < home_to_anchor - 0.005, "the hand moved toward the point"


def _mean_offset_from_line(spidar_bin, sock_dir, serve_world, k):
    fx = load_example("fixture").Fixture(k_n_per_m=k)
    served = serve_world(fx, f"unix:{sock_dir}/f{int(k)}.sock")
    run_rig(spidar_bin, "--virtual", "--world", served.address, "--script", "circle", "--seconds", 5, "--quiet")
    served.stop()
    rows = fx.log[400:-200]
    off = [_norm(fx.across([p - o for p, o in zip(pos, fx.origin_m)])) for _, pos, _ in rows]
    return fx, sum(off) / len(off)


def test_the_fixture_example_keeps_the_hand_nearer_its_line_and_pushes_only_across_it(spidar_bin, sock_dir,
                                                                                     serve_world):
    fx, guided = _mean_offset_from_line(spidar_bin, sock_dir, serve_world, 300.0)
    _, free = _mean_offset_from_line(spidar_bin, sock_dir, serve_world, 0.0)
    # The scripted arm holds its circle with 200 N/m and the rig gives at most 4 N: the guide can
    # pull the hand about 2 cm toward its line.
    assert guided < free - 0.012, f"mean distance from the line {guided} m guided, {free} m free"
    for _, _, f in fx.log:
        assert abs(sum(a * b for a, b in zip(f, fx.direction))) <= 1e-9 + 1e-6 * _norm(f)

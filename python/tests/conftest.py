"""Shared set-up of the Python client's tests: the `spidar` binary, private socket directories,
worlds served on a thread, rig runs and their recordings read back as CSV.

Why it exists: every test here runs the real rig (`spidar run`, simulated rig, rt-loop, link)
against a Python world, on the virtual clock (deterministic) or the real one, as a person would.
It must never leave a process or socket behind: every process it starts is ended by its id.
"""

import csv
import os
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "python" / "examples"


def _find_spidar():
    """$SPIDAR_BIN, else the newest target/{debug,release}/spidar, else built once here."""
    env = os.environ.get("SPIDAR_BIN")
    if env:
        return env
    found = [p for p in (REPO / "target" / "debug" / "spidar", REPO / "target" / "release" / "spidar") if p.exists()]
    if not found:
        subprocess.run(["cargo", "build", "-p", "spidar-tools"], cwd=REPO, check=True)
        found = [REPO / "target" / "debug" / "spidar"]
    return str(max(found, key=lambda p: p.stat().st_mtime))


@pytest.fixture(scope="session")
def spidar_bin():
    return _find_spidar()


@pytest.fixture
def sock_dir():
    """A private directory with a short path (Unix socket paths hold at most 107 bytes)."""
    d = tempfile.mkdtemp(prefix="spw-")
    os.chmod(d, 0o700)
    yield Path(d)
    shutil.rmtree(d, ignore_errors=True)


class Served:
    """A world served on a thread of the test process; stop() ends it (saying goodbye)."""

    def __init__(self, world, address, **kw):
        import spidar

        self.world = world
        self.report = None
        self.lines = []
        self._stop = threading.Event()
        self._bound = threading.Event()
        self.address = None

        def listening(addr):
            self.address = addr
            self._bound.set()

        def run():
            try:
                self.report = spidar.serve(world, address, on_listening=listening, say=self.lines.append,
                                           stop=self._stop.is_set, **kw)
            finally:
                self._bound.set()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert self._bound.wait(10), "the world did not bind its socket"

    def stop(self):
        self._stop.set()
        self.thread.join(10)
        assert not self.thread.is_alive(), "the world's thread did not end"
        return self.report


@pytest.fixture
def serve_world():
    served = []

    def start(world, address, **kw):
        s = Served(world, address, **kw)
        served.append(s)
        return s

    yield start
    for s in served:
        if s.thread.is_alive():
            s.stop()


def run_rig(spidar_bin, *args, timeout=120, check=True):
    """`spidar run ARGS` to the end; returns the finished process (stdout, stderr as text)."""
    p = subprocess.run([spidar_bin, "run", *map(str, args)], capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"spidar run {' '.join(map(str, args))} exited {p.returncode}:\n{p.stdout}\n{p.stderr}")
    return p


def read_csv(path):
    """A CSV written by `spidar export`: a list of rows, numbers as floats where they read."""
    rows = []
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            row = {}
            for k, v in r.items():
                try:
                    row[k] = float(v)
                except (TypeError, ValueError):
                    row[k] = v
            rows.append(row)
    return rows


def export(spidar_bin, mcap, out_dir):
    """The rig recording's channels as CSV rows: {"tick": [...], "contact_model": [...], ...}."""
    subprocess.run([spidar_bin, "export", str(mcap), "--csv", str(out_dir)], check=True, capture_output=True,
                   timeout=120)
    return {
        name: read_csv(Path(out_dir) / f"rig_{name}.csv")
        for name in ("tick", "contact_model", "hand_sample", "event")
        if (Path(out_dir) / f"rig_{name}.csv").exists()
    }


def load_example(name):
    """The module of python/examples/NAME.py."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def python_world_process(script_args, stderr_path):
    """A world as its own Python process (as a user runs one); stderr to a file."""
    with open(stderr_path, "w") as err:
        return subprocess.Popen([sys.executable, *map(str, script_args)], stdout=subprocess.DEVNULL, stderr=err,
                                cwd=REPO)

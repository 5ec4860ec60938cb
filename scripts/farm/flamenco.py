"""A Flamenco 3 farm on this machine, for the farm test (scripts/test_farm.py): building the
manager and the worker from the shared source, starting them on 127.0.0.1 only, and the parts of
the REST API that Flamenco's Blender add-on and a farm operator use.

Plain Python (urllib, subprocess), no Flamenco client package: every call is one HTTP request
with a timeout, every wait is bounded, and every process started here is stopped by `Farm.stop`
(each in a process group of its own, killed with its children).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import tarfile
import time
import urllib.error
import urllib.request
from pathlib import Path

SOURCE = "flamenco-3.9-dev-src.tar.gz"


def build(shared_farm: Path, cache: Path, log) -> tuple[Path, float]:
    """The manager and worker binaries, built once per source archive (by its hash) under
    `cache`. Returns (folder of the binaries, seconds spent building: 0 when cached)."""
    archive = shared_farm / SOURCE
    digest = hashlib.sha256(archive.read_bytes()).hexdigest()[:12]
    bin_dir = cache / f"flamenco-{digest}" / "bin"
    wanted = [bin_dir / "flamenco-manager", bin_dir / "flamenco-worker"]
    if all(p.is_file() for p in wanted):
        return bin_dir, 0.0
    start = time.monotonic()
    src = cache / f"flamenco-{digest}" / "src"
    shutil.rmtree(src, ignore_errors=True)
    src.mkdir(parents=True)
    with tarfile.open(archive) as tar:
        tar.extractall(src, filter="data")
    go = shutil.which("go") or "/usr/local/go/bin/go"
    log(f"building Flamenco from {archive} ({go} build; cached in {bin_dir.parent})")
    tmp_bin = src / "bin"
    subprocess.run([go, "build", "-o", str(tmp_bin) + "/", "./cmd/flamenco-manager",
                    "./cmd/flamenco-worker"], cwd=src, check=True, timeout=1200)
    bin_dir.mkdir(parents=True, exist_ok=True)
    for path in wanted:
        os.replace(tmp_bin / path.name, path)
    shutil.rmtree(src, ignore_errors=True)
    return bin_dir, time.monotonic() - start


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Api:
    """The manager's REST API at `url` (JSON in, JSON out)."""

    def __init__(self, url: str) -> None:
        self.url = url

    def call(self, method: str, path: str, body=None, *, raw: bool = False, timeout: float = 20):
        data = None if body is None else json.dumps(body).encode()
        request = urllib.request.Request(self.url + path, data=data, method=method,
                                         headers={"Content-Type": "application/json"})
        try:
            with urllib.request.urlopen(request, timeout=timeout) as response:
                payload = response.read()
        except urllib.error.HTTPError as error:
            raise RuntimeError(f"{method} {path}: HTTP {error.code}: "
                               f"{error.read().decode(errors='replace')[:500]}") from None
        if raw:
            return payload.decode(errors="replace")
        return json.loads(payload) if payload.strip() else None

    def job_type(self, name: str) -> dict:
        return next(t for t in self.call("GET", "/api/v3/jobs/types")["job_types"]
                    if t["name"] == name)

    def submit(self, name: str, settings: dict, *, worker_tag: str | None = None) -> dict:
        """Submit a "Simple Blender Render" job the way Flamenco's add-on does
        (`job_submission.job_for_scene` + `submit_job`): the job type's etag, the settings its
        `eval`s gave, this platform."""
        job_type = self.job_type("simple-blender-render")
        job = {"name": name, "type": job_type["name"], "type_etag": job_type["etag"],
               "priority": 50, "settings": settings, "metadata": {"project": "splat farm test"},
               "submitter_platform": "linux", "initial_status": "queued"}
        if worker_tag:
            job["worker_tag"] = worker_tag
        return self.call("POST", "/api/v3/jobs", job)

    def job(self, job_id: str) -> dict:
        return self.call("GET", f"/api/v3/jobs/{job_id}")

    def tasks(self, job_id: str) -> list[dict]:
        return self.call("GET", f"/api/v3/jobs/{job_id}/tasks")["tasks"]

    def task(self, task_id: str) -> dict:
        return self.call("GET", f"/api/v3/tasks/{task_id}")

    def task_log(self, task_id: str) -> str:
        """The whole log of a task (what the worker sent: Blender's output included)."""
        info = self.call("GET", f"/api/v3/tasks/{task_id}/log")
        if not info:
            return ""
        return self.call("GET", "/" + info["url"].lstrip("/"), raw=True)

    def workers(self) -> list[dict]:
        return self.call("GET", "/api/v3/worker-mgt/workers")["workers"]


class Farm:
    """A manager and workers, all on 127.0.0.1, under `home` (a folder of its own)."""

    def __init__(self, bin_dir: Path, home: Path, storage: Path, blender: Path, log) -> None:
        self.bin_dir, self.home, self.storage, self.blender = bin_dir, home, storage, blender
        self.log = log
        self.port = free_port()
        self.api = Api(f"http://127.0.0.1:{self.port}")
        self.processes: dict[str, subprocess.Popen] = {}

    def _spawn(self, name: str, argv: list[str], cwd: Path, env: dict) -> subprocess.Popen:
        cwd.mkdir(parents=True, exist_ok=True)
        out = open(cwd / f"{name}.log", "ab")
        process = subprocess.Popen(argv, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL, start_new_session=True)
        out.close()
        self.processes[name] = process
        return process

    def start_manager(self, *, fail_after: int = 1) -> None:
        cwd = self.home / "manager"
        cwd.mkdir(parents=True, exist_ok=True)
        # Every key that matters is written out: no first-run assistant, no discovery broadcast,
        # no Shaman (the .blend files go to shared storage as they are), one listening address.
        (cwd / "flamenco-manager.yaml").write_text(f"""_meta:
  version: 3
manager_name: splat farm test
database: flamenco-manager.sqlite
listen: 127.0.0.1:{self.port}
autodiscoverable: false
local_manager_storage_path: {cwd / "flamenco-manager-storage"}
shared_storage_path: {self.storage}
shaman:
  enabled: false
task_timeout: 10m0s
worker_timeout: 1m0s
blocklist_threshold: 3
task_fail_after_softfail_count: {fail_after}
variables:
  blender:
    values:
      - platform: linux
        value: {self.blender}
  blenderArgs:
    values:
      - platform: all
        value: -b -y
""")
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(cwd)}
        self._spawn("manager", [str(self.bin_dir / "flamenco-manager")], cwd, env)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.processes["manager"].poll() is not None:
                raise RuntimeError(f"the manager exited: see {cwd / 'manager.log'}")
            try:
                self.api.call("GET", "/api/v3/version", timeout=2)
                return
            except (OSError, RuntimeError):
                time.sleep(0.5)
        raise RuntimeError(f"the manager did not answer within 60 s: see {cwd / 'manager.log'}")

    def start_worker(self, name: str, blender_env: dict, *, timeout: float = 60) -> dict:
        """A worker named `name` (its own folder, credentials and database), running Blender
        through the wrapper with `blender_env` (SPLAT_FARM_HOME: the worker user's Blender home).
        Waits until the manager sees it awake; returns the manager's record of it."""
        cwd = self.home / "workers" / name
        cwd.mkdir(parents=True, exist_ok=True)
        (cwd / "flamenco-worker.yaml").write_text(
            f"worker_name: {name}\nmanager_url: {self.api.url}/\n"
            "task_types: [blender, file-management, misc]\n")
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(cwd),
               "XDG_CONFIG_HOME": str(cwd / "config"), "XDG_DATA_HOME": str(cwd / "data"),
               **blender_env}
        self._spawn(name, [str(self.bin_dir / "flamenco-worker"), "-manager", self.api.url],
                    cwd, env)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.processes[name].poll() is not None:
                raise RuntimeError(f"worker {name} exited: see {cwd / (name + '.log')}")
            for worker in self.api.workers():
                if worker["name"] == name and worker["status"] == "awake":
                    return worker
            time.sleep(0.5)
        raise RuntimeError(f"worker {name} was not awake within {timeout:.0f} s")

    def kill(self, name: str) -> None:
        """SIGKILL the process group of `name` (the worker and the Blender it runs): a machine
        that dies, no sign-off."""
        process = self.processes.pop(name, None)
        if process is None or process.poll() is not None:
            return
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait(timeout=30)

    def stop_worker(self, name: str) -> None:
        """A clean stop: SIGTERM (the worker signs off), SIGKILL after 20 s."""
        process = self.processes.pop(name, None)
        if process is None or process.poll() is not None:
            return
        with_group = lambda sig: os.killpg(process.pid, sig)  # noqa: E731
        try:
            with_group(signal.SIGTERM)
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            with_group(signal.SIGKILL)
            process.wait(timeout=30)
        except ProcessLookupError:
            pass

    def stop(self) -> None:
        for name in [n for n in self.processes if n != "manager"]:
            self.stop_worker(name)
        self.stop_worker("manager")

    def wait_job(self, job_id: str, *, timeout: float, on_poll=None) -> tuple[dict, list[dict]]:
        """Poll the job until its render tasks are all done (completed, failed or canceled) or
        `timeout` seconds pass; `on_poll(job, tasks)` is called on each poll (fault injection).
        The job's "preview-video" task (FFmpeg) is left out: these workers have no FFmpeg (a
        Flamenco release bundles one; a source build does not), so they do not offer the
        task type and the task waits; the job is then cancelled. Returns (job, tasks)."""
        deadline = time.monotonic() + timeout
        while True:
            job, tasks = self.api.job(job_id), self.api.tasks(job_id)
            if on_poll is not None:
                on_poll(job, tasks)
            render = [t for t in tasks if t["task_type"] != "ffmpeg"]
            finished = job["status"] in ("completed", "failed", "canceled") or (
                render and all(t["status"] in ("completed", "failed", "canceled") for t in render))
            if finished or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        if job["status"] not in ("completed", "failed", "canceled"):
            self.api.call("POST", f"/api/v3/jobs/{job_id}/setstatus",
                          {"status": "cancel-requested",
                           "reason": "farm test: render tasks done; no FFmpeg worker for the "
                                     "preview video"})
        return job, tasks

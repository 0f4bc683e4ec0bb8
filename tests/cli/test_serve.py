"""``python -m grt.serve`` and ``policy=remote`` end to end: a GRT policy served from a separate process and
red-teamed through the protocol scores exactly as in process; the failures are one line and exit code 2."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from grt.policy_server import PolicyServer
from tests.conftest import GRASP_EVALUATION

ROOT = Path(__file__).resolve().parents[2]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _terminal_sigint() -> None:
    """SIGINT as a terminal gives it (default action, not blocked): a process inherits an ignored or blocked
    SIGINT from its parent (an earlier test of the pytest worker may leave it so, as `cmd &` does in a script)
    and then never sees Ctrl-C, by Unix's rules; the Ctrl-C test hung in the full suite alone."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Served:
    """``python -m grt.serve ARGS`` (or another command) as a subprocess; its first line is the URL."""

    def __init__(self, *args: str, command: list[str] | None = None, cwd: Path = ROOT):
        self.proc = subprocess.Popen(command or [sys.executable, "-m", "grt.serve", *args], cwd=cwd, env=ENV,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                     preexec_fn=_terminal_sigint)
        self.url = self.proc.stdout.readline().strip()
        threading.Thread(target=self.proc.stdout.read, daemon=True).start()  # never block the server on a pipe
        threading.Thread(target=self.proc.stderr.read, daemon=True).start()
        assert self.url.startswith("ws://127.0.0.1:"), f"first line {self.url!r}"

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
        self.proc.wait()

    def __enter__(self) -> Served:
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()


def grt(app: str, *args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"grt.{app}", *args], cwd=ROOT, env=ENV, capture_output=True,
                          text=True, timeout=timeout)


def trials(folder: Path) -> list[tuple]:
    """(seed, mode, score, info without timings) of every trial of an evaluation folder."""
    record = json.loads((folder / "evaluation.json").read_text())
    drop = ("wall_s", "capture_s", "plan_s", "sim_s")
    return [(t["seed"], t["mode"], t["score"], {k: v for k, v in t["info"].items() if k not in drop})
            for t in record["trials"]]


def evaluate_served_and_in_process(tmp_path: Path, url: str, policy: str, *args: str) -> tuple[list, list]:
    """The trials of ``grt.evaluate ARGS`` through ``policy=remote`` and with ``policy=POLICY`` in process."""
    common = [*args, "budget.workers=1", "evaluator.progress=false"]
    found = []
    for name, given in (("remote", ["policy=remote", f"policy.url={url}"]), ("local", [f"policy={policy}"])):
        proc = grt("evaluate", *given, *common, f"hydra.run.dir={tmp_path / name}")
        assert proc.returncode == 0, proc.stderr[-2000:]
        found.append(trials(tmp_path / name))
    return found[0], found[1]


def test_no_server_is_one_line_naming_the_url_before_any_simulation(tmp_path):
    url = f"ws://127.0.0.1:{free_port()}"
    proc = grt("evaluate", "task=insertion", "policy=remote", f"policy.url={url}", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: no policy server at {url}"), proc.stderr
    assert not (tmp_path / "evaluation.json").exists()


@pytest.mark.parametrize(("args", "token", "message"), [
    (["task=insertion"], None, "serves greedy 1 (batched policy for 'point_mass'), but the run's task is 'insertion'"),
    pytest.param(["task=insertion"], "s3cret", "refused the connection: bad or missing token",
                 marks=pytest.mark.slow)])
def test_handshake_mismatch_and_bad_token_are_one_line(tmp_path, args, token, message):
    server = PolicyServer(act=lambda obs: np.zeros((1, 2)), kind="batched", task="point_mass", obs={"state": [4]},
                          action_size=2, name="greedy", version="1", port=0, token=token)
    with server:
        proc = grt("evaluate", *args, "policy=remote", f"policy.url={server.url}", f"hydra.run.dir={tmp_path}")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: policy server {server.url} {message}"), proc.stderr


@pytest.mark.slow
def test_the_shipped_insertion_policy_served_scores_as_in_process(tmp_path):
    with Served("policy=insertion_state", "serve.port=0") as server:
        remote, local = evaluate_served_and_in_process(tmp_path, server.url, "insertion_state", "task=insertion",
                                                       "budget.trials=3")
        server.proc.send_signal(signal.SIGTERM)  # a scheduler's stop: exit code 143 as every app (0 before)
        assert server.proc.wait(timeout=60) == 143
    assert remote == local


def test_a_port_out_of_range_is_one_line_before_the_policy_loads():
    """``serve.port=-5`` ended in an OverflowError traceback."""
    from grt.cli.serve import make_server
    from grt.policies.base import PolicyServerError
    from tests.runner.conftest import compose_run

    for port in (-5, 70000):
        cfg = compose_run([f"serve.port={port}", "policy.checkpoint=/nonexistent.pt"], config_name="serve")
        with pytest.raises(PolicyServerError, match=rf"^serve.port={port}: a port is a whole number from 1 to 65535"):
            make_server(cfg)  # before the (here missing) checkpoint is read


@pytest.mark.slow
def test_the_antipodal_planner_served_scores_as_in_process(grasp_evaluation, tmp_path):
    """The in-process side is conftest.py's evaluation (python -m grt.evaluate GRASP_EVALUATION, shared);
    served, the same command with policy=remote."""
    with Served("task=grasp_2cam", "policy=antipodal", "serve.port=0") as server:
        args = [a for a in GRASP_EVALUATION if not a.startswith("policy=")]
        proc = grt("evaluate", *args, "policy=remote", f"policy.url={server.url}", "evaluator.progress=false",
                   f"hydra.run.dir={tmp_path / 'remote'}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    remote, local = trials(tmp_path / "remote"), trials(grasp_evaluation[0])
    assert remote == local
    assert any(t[3].get("num_grasps") for t in remote)  # grasps crossed the wire


@pytest.mark.slow
def test_a_server_killed_mid_run_stops_it_cleanly_and_resume_finishes_it(tmp_path):
    """The server dies during the search and stays down: one line naming resume; served again: resume ends."""
    port, run_dir = free_port(), tmp_path / "run"
    delayed = [sys.executable, str(Path(__file__).with_name("_serve_delayed.py")), str(port), "0.15"]
    args = ["task=insertion", "budget=smoke", "policy=remote", f"policy.url=ws://127.0.0.1:{port}",
            "policy.retries=1", "policy.retry_wait=0.2", f"hydra.run.dir={run_dir}"]
    with Served(command=delayed) as server:
        run = subprocess.Popen([sys.executable, "-m", "grt.run", *args], cwd=ROOT, env=ENV, text=True,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        journal = run_dir / "journal.jsonl"
        for _ in range(600):  # kill it once the nominal object is journaled, while the search runs
            if journal.exists() and journal.read_text().count("\n") >= 1:
                break
            threading.Event().wait(0.2)
        server.kill()
        out, err = run.communicate(timeout=120)
    lines = journal.read_text().count("\n")
    assert run.returncode == 2 and "Traceback" not in err, err[-2000:]
    said = [line for line in err.splitlines() if line.startswith("error:")]  # one line on stderr
    assert len(said) == 1 and "is down" in said[0] and f"python -m grt.run resume={run_dir}" in said[0], out + err
    assert 1 <= lines < 7  # smoke: 1 nominal + 3 x 2 candidates
    with Served(command=delayed[:-1] + ["0"]):
        resumed = grt("run", f"resume={run_dir}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert journal.read_text().count("\n") == 7 and (run_dir / "summary.json").exists()


@pytest.mark.parametrize(("args", "message"), [
    (["task=drawer", "policy=insertion_state"], "was trained for task 'insertion', but the run's task is 'drawer'"),
    pytest.param(["task=insertion", "policy=antipodal"], "policy=antipodal is a grasp planner, task=insertion is a "
                 "closed-loop", marks=pytest.mark.slow)])
def test_serving_a_policy_for_another_task_is_one_line(args, message):
    proc = grt("serve", *args, "serve.port=0", timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr and not proc.stdout.strip()
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], proc.stderr


@pytest.mark.slow
def test_a_taken_port_is_one_line():
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = grt("serve", "policy=insertion_servo", f"serve.port={port}", timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: cannot listen on 127.0.0.1:{port} (Address already in use")
    assert "pick another serve.port (0: any free one) or serve.host" in lines[0], proc.stderr


@pytest.mark.slow
def test_the_documented_server_of_your_own_act_function_runs(tmp_path):
    """docs/remote-policies.md's example, as written (a scripted network stands in for the user's file)."""
    import torch

    text = (ROOT / "docs" / "remote-policies.md").read_text()
    code = text.split("```python\n", 1)[1].split("```", 1)[0]
    assert len(code.strip().splitlines()) <= 25
    torch.jit.save(torch.jit.script(torch.nn.Linear(24, 6)), tmp_path / "my_insertion_policy.pt")
    (tmp_path / "policy_server.py").write_text((ROOT / "grt" / "policy_server.py").read_text())
    (tmp_path / "serve_my_policy.py").write_text(code.replace("port=8000", "port=0"))
    from grt.policies.remote import connect

    with Served(command=[sys.executable, "serve_my_policy.py"], cwd=tmp_path) as server:
        policy = connect(server.url)
        policy.check("insertion", {"state": (24,), "grip": (6,), "cloud": (500, 3)}, 6)
        policy.reset(0)
        action = policy.act({"state": np.ones((2, 24), np.float32), "cloud": np.zeros((2, 500, 3), np.float32)})
        assert action.shape == (2, 6) and policy.name.startswith("my-insertion-policy")
        policy.close()


@pytest.mark.slow
def test_a_server_leaves_no_folder_behind(tmp_path):
    """Each start left ``outputs/serve/<time>/serve.log`` behind (its one line: the URL it printed)."""
    with Served("policy=insertion_state", "serve.port=0", cwd=tmp_path) as server:
        server.proc.send_signal(signal.SIGINT)  # how a server is stopped by hand
        assert server.proc.wait(timeout=60) == 0
    assert not any((tmp_path / "outputs" / "serve").iterdir()) if (tmp_path / "outputs" / "serve").exists() else True

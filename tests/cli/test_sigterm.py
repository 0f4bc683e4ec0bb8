"""SIGTERM (``kill``, ``timeout``, a scheduler) stops every command with one line, ``terminated (SIGTERM)``,
and exit code 143 (Ctrl-C: ``interrupted (Ctrl-C)``, 130)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from grt.cli._common import AppParser, exit_on_user_error
from grt.errors import Terminated
from grt.redteam import episode_seeds
from tests.cli.test_run_faults import ROOT, SESSION_PATH


@pytest.mark.parametrize(("stop", "line", "code"), [(Terminated, "terminated (SIGTERM)", 143),
                                                    (KeyboardInterrupt, "interrupted (Ctrl-C)", 130)])
def test_the_apps_error_path_tells_sigterm_from_ctrl_c(stop, line, code, capsys):
    """The path of every app (``grt.report``, ``grt.replay``, ``grt.deform``, ... and inside the Hydra apps)."""
    with pytest.raises(SystemExit) as info, exit_on_user_error():
        raise stop
    assert info.value.code == code and capsys.readouterr().err == f"{line}\n"


def test_the_apps_without_hydra_take_sigterm_as_a_stop():
    saved = signal.getsignal(signal.SIGTERM)
    try:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        AppParser("report")
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler)
        with pytest.raises(Terminated):
            handler(signal.SIGTERM, None)
    finally:
        signal.signal(signal.SIGTERM, saved)


def test_sigterm_to_an_evaluation_is_one_line_and_exit_143(tmp_path):
    """``grt.evaluate`` said "interrupted (Ctrl-C)" and exited 130 (a real worker pool, its trial hanging)."""
    first = episode_seeds(42, 2)[0]  # budget=quick's seed
    env = {**os.environ, "WANDB_MODE": "disabled",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(SESSION_PATH), str(ROOT), os.environ.get("PYTHONPATH")]))}
    printed = tmp_path / "stdout.txt"
    proc = subprocess.Popen(
        [sys.executable, "-m", "grt.evaluate", "object=can", "budget.trials=2", "budget.workers=1",
         "~task.session", f"+task.session={{_target_:_toy_session.ToySession,hang_on:{first}}}", "~policy",
         "+policy={_target_:_toy_session.ToyPolicy}", f"hydra.run.dir={tmp_path / 'out'}"],
        cwd=ROOT, stdout=printed.open("w"), stderr=subprocess.PIPE, text=True, env=env)
    end = time.monotonic() + 120
    while "ready in" not in printed.read_text():  # the workers are up, the first trial hangs
        assert proc.poll() is None and time.monotonic() < end, proc.communicate()[1][-3000:]
        time.sleep(0.1)
    time.sleep(1)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-3000:]
    assert "Traceback" not in printed.read_text() + err, err[-3000:]
    assert err.strip().splitlines()[-1] == "terminated (SIGTERM)", err[-3000:]

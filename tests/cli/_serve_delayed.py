"""``python _serve_delayed.py PORT DELAY``: the shipped insertion_state policy served with DELAY seconds per
action (a slow network policy), so that a test can kill the server in the middle of a run."""

import sys
import time
from pathlib import Path

from grt.policies.rsl_rl import RslRlPolicy
from grt.policy_server import PolicyServer

policy = RslRlPolicy(str(Path(__file__).resolve().parents[2] / "grt/policies/checkpoints/insertion_state.pt"))
delay = float(sys.argv[2])


def act(obs):
    time.sleep(delay)
    return policy.act(obs)


server = PolicyServer(act=act, reset=policy.reset, kind="batched", task="insertion", obs=policy.input_spec,
                      action_size=policy.num_actions, name="insertion_state-delayed", version="1",
                      port=int(sys.argv[1]))
print(server.url, flush=True)
server.serve_forever()

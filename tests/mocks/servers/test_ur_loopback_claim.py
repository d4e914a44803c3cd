"""The twin's UR controllers claim their loopback address (mocks/servers/ur/twin_controller.py claim_loopback): two
processes that look at once never take the same one (make test runs the UR modules on two workers side by side)."""

import subprocess
import sys

from trackcal.mocks.servers.ur.twin_controller import FIRST_HOST, claim_loopback

CLAIM_IN_A_CHILD = (
    "from trackcal.mocks.servers.ur.twin_controller import claim_loopback; host, claim = claim_loopback(); print(host)"
)


def test_a_held_claim_keeps_the_address_from_this_process_and_from_another():
    host, claim = claim_loopback()
    try:
        assert int(host.rsplit(".", 1)[1]) >= FIRST_HOST
        other, second = claim_loopback()
        second.close()
        child = subprocess.run([sys.executable, "-c", CLAIM_IN_A_CHILD], capture_output=True, text=True, check=True)
        assert host != other and host != child.stdout.strip()
    finally:
        claim.close()

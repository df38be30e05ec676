"""The service's router maps no other process's shared memory (issue 20: memory bounded under
any input).

zenoh sends a message of more than a few kB between two processes on one host through a
shared-memory pool of the sender's (16 MB by default), which the receiver maps. A local process
flooding the service with large payloads would so leave 16 MB of its pool resident in the
service (seen in ``firetrack bench faults``: VmRSS +16 MB, all of it RssShmem, kept after the
flood). The wearables are on the network, where shared memory plays no part, so the service's
router does without it.
"""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from tests.zenoh_util import router, wait_until

SENDER = textwrap.dedent("""
    import sys, time, zenoh
    from service.protocol.session import client_config
    s = zenoh.open(client_config(sys.argv[1]))
    pub = s.declare_publisher("firetrack/demo/big/imu", congestion_control=zenoh.CongestionControl.BLOCK)
    deadline = time.monotonic() + 10.0
    while not pub.matching_status.matching and time.monotonic() < deadline:  # the route to the subscriber
        time.sleep(0.01)
    for i in range(20):
        pub.put(bytes(200_000))
    time.sleep(0.5)
    s.close()
""")


def _zenoh_shm_mappings() -> list[str]:
    return sorted({line.split()[-1] for line in Path("/proc/self/maps").read_text().splitlines()
                   if line.rstrip().endswith(".zenoh")})


def test_large_payloads_from_a_local_process_leave_no_shared_memory_mapped_in_the_service():
    if not Path("/proc/self/maps").exists():
        import pytest

        pytest.skip("needs /proc (Linux) to see the process's mappings")
    before = _zenoh_shm_mappings()
    session, endpoint = router()
    got = []
    sub = session.declare_subscriber("firetrack/demo/*/imu", lambda s: got.append(len(s.payload)))
    try:
        subprocess.run([sys.executable, "-c", SENDER, endpoint], timeout=60, check=True)
        assert wait_until(lambda: len(got) == 20, timeout=10.0), f"{len(got)} of 20 payloads arrived"
        assert set(got) == {200_000}
        assert _zenoh_shm_mappings() == before  # the sender's pool was not mapped here
    finally:
        sub.undeclare()
        session.close()

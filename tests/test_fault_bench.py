"""`firetrack bench faults` end to end, small: a real service, router and attacker process on
loopback, two short attacks and a control run compared with it (the figures themselves are the
benchmark's to report; here: that every part of it runs and says what it measured)."""
from __future__ import annotations

import subprocess
import sys

from client.fault_bench import against_control, bench_faults, pooled, pooled_against_control


def test_the_fault_bench_runs_two_attacks_and_compares_with_a_control_run():
    kw = {"attack_s": 3.0, "phase_s": 3.0, "expire_after": 2.0, "bystanders": 1, "log": lambda m: None, "n_attacks": 2,
          "settle_s": 1.0}
    control = bench_faults("flood", 0, **kw)
    attack = bench_faults("flood", 600, **kw)
    assert control["attacker"].startswith("sent 0 ") and float(control["attacker"].split()[2]) >= 3.0
    assert [a["attacker"].split()[1] for a in attack["attacks"]] == ["600", "600"]
    for run in (control, attack):
        assert run["bystanders"]["during"]["poses"] > 0 and run["bystanders"]["before"]["poses"] > 0
        assert run["service_cpu_per_s"]["during"] > 0
        slow = run["slowest_during"]  # [s into the attack, ms, service ms, responder], slowest first
        assert 0 < len(slow) <= 5 and [r[1] for r in slow] == sorted((r[1] for r in slow), reverse=True)
        assert all(0 <= r[0] <= run["attack_s"] + 0.5 and r[3].startswith("bystander") for r in slow)
        assert len(run["attacks"]) == 2 and run["anon_mb"]["before"] > 0
    assert control["log_growth_bytes"] < attack["log_growth_bytes"]  # the attack's rejects are logged, summarised
    assert attack["honest_status"]["rejected"]  # the hostile frames on the honest key were counted against it
    cmp = against_control(attack, control)
    assert cmp["latency_p99_during_over_control"] == round(
        attack["bystanders"]["during"]["latency_p99_ms"] / control["bystanders"]["during"]["latency_p99_ms"], 3)

    # pooled over runs (--pairs): one run pooled is that run; two runs pool all their poses
    for run in (control, attack):
        one, during = pooled([run]), run["bystanders"]["during"]
        assert (one["poses"], one["latency_p99_ms"], one["service_latency_p99_ms"]) == (
            during["poses"], during["latency_p99_ms"], during["service_latency_p99_ms"])
    assert pooled([control, attack])["poses"] == sum(r["bystanders"]["during"]["poses"] for r in (control, attack))
    assert pooled_against_control([attack], [control])["latency_p99_during_over_control"] == \
        cmp["latency_p99_during_over_control"]


def test_pairs_without_a_control_run_are_refused_with_the_reason():
    p = subprocess.run([sys.executable, "-m", "client.entry", "bench", "faults", "--pairs", "2", "--no-cost"],
                       capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--pairs needs --control" in p.stderr

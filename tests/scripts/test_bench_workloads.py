"""scripts/bench_workloads.py's timing loop: interleaved rounds, and the opt-in warm repeats."""

from __future__ import annotations


def test_warm_repeats_follow_each_timed_call_except_one_round_cases(bench_workloads) -> None:
    bench = bench_workloads
    calls: list[str] = []
    fast = bench.Case("distance field", "2K cloud", "fast", lambda: calls.append("fast"))
    slow = bench.Case("1K × 1K", "5K mesh", "exact", lambda: calls.append("slow"), runs=1)
    bench.run_cases([fast, slow], runs=3, warm=2)
    # a warm-up round, then three rounds of the timed call and its two repeats
    assert calls.count("fast") == 1 + 3 * (1 + 2)
    assert len(fast.cpu) == len(fast.warm) == 3 and all(t >= 0 for t in fast.warm)
    # a one-round case: its warm-up and one timed call, never repeated
    assert calls.count("slow") == 2 and len(slow.cpu) == 1 and slow.warm == []
    plain = bench.Case("one pair", "2K cloud", "fast", lambda: calls.append("plain"))
    bench.run_cases([plain], runs=2)  # no --warm: the interleaved timings only
    assert calls.count("plain") == 3 and plain.warm == []

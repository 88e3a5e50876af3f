"""The selection's memos: exact keys, the memory budget, the least recently used dropped first."""
import numpy as np

from hybridfmu.diagnosis.memo import DesignMemo, LruMemo, setting_key


def test_settings_that_differ_in_the_last_bit_are_two_entries():
    shift = -4.166666669236275e-05
    near = np.nextafter(shift, 0.0)
    assert setting_key({"shift_s": shift, "scale": 1.0}) == setting_key({"scale": 1.0, "shift_s": shift})
    assert setting_key({"shift_s": shift}) != setting_key({"shift_s": near})
    memo = DesignMemo()
    calls = []
    for value in (shift, near, shift):
        design = memo.get(("time_offset", setting_key({"shift_s": value})),
                          lambda value=value: calls.append(value) or np.full(3, value))
        assert design[0] == value  # each caller gets the design of the setting it asked for
    assert calls == [shift, near]  # the third request is a hit on the first


def test_design_memo_keeps_to_its_budget_and_returns_read_only_arrays():
    memo = DesignMemo(budget_bytes=2 * 8 * 10)
    for key in range(3):
        memo.get(key, lambda key=key: np.full(10, float(key)))
    recomputed = []
    memo.get(0, lambda: recomputed.append(0) or np.zeros(10))  # dropped: the least recently used
    memo.get(2, lambda: recomputed.append(2) or np.zeros(10))  # kept
    assert recomputed == [0]
    array = memo.get(2, lambda: np.zeros(10))
    assert not array.flags.writeable


def test_lru_memo_drops_the_least_recently_used():
    memo = LruMemo(entries=2)
    memo.put("a", 1)
    memo.put("b", 2)
    assert memo.get("a") == 1  # "b" is now the least recently used
    memo.put("c", 3)
    assert memo.get("b") is None and memo.get("a") == 1 and memo.get("c") == 3

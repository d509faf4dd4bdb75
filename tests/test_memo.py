"""The keyed LRU memo behind build_plant's plants and the simulators' shared closed loops."""

from __future__ import annotations

import gc
import weakref

import pytest

from thsa_control.memo import KeyedLRU


class _Obj:
    pass


def test_least_recently_used_is_dropped_and_a_hit_is_not_rebuilt():
    memo, built = KeyedLRU(2), []

    def build(v):
        return lambda: built.append(v) or v

    assert memo.get("a", build(1)) == 1 and memo.get("b", build(2)) == 2
    assert memo.get("a", build(10)) == 1  # a hit: not built again, and now the most recently used
    assert memo.get("c", build(3)) == 3
    assert list(memo.keys()) == ["a", "c"] and len(memo) == 2 and "b" not in memo
    assert built == [1, 2, 3]
    assert memo.get("b", build(20)) == 20  # dropped: built again


def test_failed_build_stores_nothing():
    memo = KeyedLRU(4)

    def boom():
        raise RuntimeError("no")

    with pytest.raises(RuntimeError):
        memo.get("k", boom)
    assert "k" not in memo and len(memo) == 0
    assert memo.get("k", lambda: 5) == 5


def test_kept_objects_live_as_long_as_their_entry():
    """The objects whose id is in a key stay alive with the entry (an id cannot be reused), and are freed
    with it."""
    memo = KeyedLRU(1)
    obj = _Obj()
    ref = weakref.ref(obj)
    memo.get(id(obj), lambda: "value", keep=obj)
    del obj
    gc.collect()
    assert ref() is not None
    memo.get("other", lambda: "x")  # drops the first entry
    gc.collect()
    assert ref() is None


@pytest.mark.parametrize("size", [0, -1, 1.5, None])
def test_size_must_be_a_positive_integer(size):
    with pytest.raises(ValueError, match="size"):
        KeyedLRU(size)

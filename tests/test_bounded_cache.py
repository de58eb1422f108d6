"""station/compute/bounded_cache.py: the caches the rim detector and the wheel fit share between threads."""

from __future__ import annotations

import threading

from station.compute.bounded_cache import BoundedCache


def test_keeps_values_and_drops_the_oldest():
    cache = BoundedCache(2)
    made = []

    def make(k):
        return lambda: made.append(k) or k * 10

    assert cache.get(1, make(1)) == 10 and cache.get(1, make(1)) == 10 and made == [1]
    cache.get(2, make(2))
    cache.get(3, make(3))  # full: 1 goes
    assert len(cache) == 2
    assert cache.get(1, make(1)) == 10 and made == [1, 2, 3, 1]


def test_many_threads_filling_a_small_cache_never_fail():
    cache = BoundedCache(3)
    errors = []

    def work(t):
        try:
            for i in range(2000):
                key = (t * 7 + i) % 11
                assert cache.get(key, lambda: key * 2) == key * 2
        except Exception as e:  # noqa: BLE001 - the test records any failure of a thread
            errors.append(e)

    threads = [threading.Thread(target=work, args=(t,)) for t in range(8)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors and len(cache) <= 3

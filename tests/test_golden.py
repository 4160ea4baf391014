"""Byte-identity: every built-in scenario's metrics.json and log.npz match the stored digests."""
import json

from tests.golden.digest import DIGESTS, compute


def test_builtin_outputs_are_byte_identical_to_stored_digests():
    stored = json.loads(DIGESTS.read_text())
    now = compute()
    assert sorted(now) == sorted(stored), "the set of built-in scenarios changed: regenerate the digests"
    changed = [f"{key}:{f}" for key in stored for f in stored[key] if now[key][f] != stored[key][f]]
    assert not changed, f"outputs changed (regenerate only for an intended change): {changed}"

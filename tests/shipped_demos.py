"""The shipped demos the tests expect (file stems in rtdenoise/assets/models/): one list, so a
new or renamed demo is named once; test_examples.py checks it against the files."""

from __future__ import annotations

SHIPPED_DEMOS = ("afn", "wskp", "wskp-small", "nbg", "affinity", "affinity-small", "crossreg")

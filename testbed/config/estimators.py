"""`[[estimators]]` of a scenario: which plugin estimators a run scores besides its pipeline."""
from __future__ import annotations

import re
from dataclasses import dataclass, field

from testbed.config import require

_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]*")


@dataclass(frozen=True, kw_only=True, slots=True)
class EstimatorSpec:
    """One `[[estimators]]` table.

    entry: a registered name (`testbed estimators`), `package.module:Name` or
    `path/to/file.py:Name` (a path relative to the working directory); name: the key of its
    scores in metrics.json `estimators` (default: the registered name or the class name);
    params: free table handed to the estimator (Context.params and the constructor's `params`).
    """

    entry: str
    name: str = ""
    params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        require(bool(self.entry.strip()), "entry", self.entry, "must name an estimator (see `testbed estimators`)")
        require(not self.name or _NAME.fullmatch(self.name) is not None, "name", self.name,
                "letters, digits, '_', '-' and '.' only")

    @property
    def key(self) -> str:
        """The metrics.json key: name, else the part after ':' of the entry, else the entry."""
        return self.name or self.entry.rpartition(":")[2] or self.entry

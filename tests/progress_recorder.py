"""A :class:`allorules.runs.progress.RunProgress` that records what a run told it (for tests)."""
from __future__ import annotations

from allorules.runs.progress import RunProgress


class RecordingProgress(RunProgress):
    def __init__(self):
        self.events: list[tuple] = []

    def step_started(self, step, steps):
        self.events.append(("started", step, steps))

    def basis(self, done, total):
        self.events.append(("basis", done, total))

    def trial(self, count, misfit):
        self.events.append(("trial", count, misfit))

    def step_finished(self, step, steps):
        self.events.append(("finished", step, steps))

    def check(self, steps: int, trials_per_step: list[int]) -> None:
        """Each step: started, its basis complete, its trials counted 1, 2, …, then finished."""
        kinds = [event[0] for event in self.events]
        assert kinds.count("started") == kinds.count("finished") == steps
        starts = [index for index, kind in enumerate(kinds) if kind == "started"] + [len(kinds)]
        for step in range(steps):
            events = self.events[starts[step]:starts[step + 1]]
            assert events[0] == ("started", step + 1, steps) and events[-1] == ("finished", step + 1, steps)
            bases = [event for event in events if event[0] == "basis"]
            assert bases and bases[-1][1] == bases[-1][2]            # the basis was reported complete
            counts = [event[1] for event in events if event[0] == "trial"]
            assert counts == list(range(1, trials_per_step[step] + 1))
            misfits = [event[2] for event in events if event[0] == "trial"]
            assert all(later <= earlier for earlier, later in zip(misfits, misfits[1:]))   # best so far

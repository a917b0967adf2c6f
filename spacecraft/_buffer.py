"""The onboard command buffer (the PUS 11 time-based schedule): accepted, not yet executed
commands, ordered by time tag.

At most one joint command per tag (the vehicle refuses a second one before it gets here);
attitude-control commands may share a tag and then execute in seq order (the last wins).
"""

from __future__ import annotations

import bisect
from collections.abc import Callable

from telemetry.wire import AcsCommandMsg, JointCommandMsg

__all__ = ["CommandBuffer"]

Command = JointCommandMsg | AcsCommandMsg


class CommandBuffer:
    def __init__(self) -> None:
        self._joints: dict[int, JointCommandMsg] = {}
        self._joint_tags: list[int] = []  # sorted
        self._acs: dict[int, list[AcsCommandMsg]] = {}
        self._n_acs = 0

    def __len__(self) -> int:
        return len(self._joints) + self._n_acs

    @property
    def joints_queued(self) -> int:
        return len(self._joints)

    def add(self, command: Command) -> None:
        tag = command.execute_time_ns
        if isinstance(command, JointCommandMsg):
            self._joints[tag] = command
            bisect.insort(self._joint_tags, tag)
        else:
            self._acs.setdefault(tag, []).append(command)
            self._n_acs += 1

    def joint_taken_by(self, tag_ns: int) -> JointCommandMsg | None:
        """The queued joint command that already holds this tag, if any."""
        return self._joints.get(tag_ns)

    def first_joint(self) -> JointCommandMsg | None:
        """The queued joint command with the earliest tag."""
        return self._joints[self._joint_tags[0]] if self._joint_tags else None

    def joint_neighbours(
        self, tag_ns: int
    ) -> tuple[JointCommandMsg | None, JointCommandMsg | None]:
        """The queued joint commands just before and just after ``tag_ns``."""
        i = bisect.bisect_left(self._joint_tags, tag_ns)
        before = self._joints[self._joint_tags[i - 1]] if i > 0 else None
        j = bisect.bisect_right(self._joint_tags, tag_ns)
        after = self._joints[self._joint_tags[j]] if j < len(self._joint_tags) else None
        return before, after

    def next_tag_ns(self) -> int | None:
        """The earliest tag in the buffer (None when it is empty)."""
        tags = self._joint_tags[:1] + ([min(self._acs)] if self._acs else [])
        return min(tags) if tags else None

    def last_tag_ns(self) -> int | None:
        """The latest tag in the buffer (None when it is empty)."""
        tags = self._joint_tags[-1:] + ([max(self._acs)] if self._acs else [])
        return max(tags) if tags else None

    def pop_due(self, tag_ns: int) -> list[Command]:
        """The commands tagged exactly ``tag_ns``, in sequence order, removed from the buffer."""
        due: list[Command] = []
        joint = self._joints.pop(tag_ns, None)
        if joint is not None:
            self._joint_tags.remove(tag_ns)
            due.append(joint)
        acs = self._acs.pop(tag_ns, [])
        self._n_acs -= len(acs)
        due += acs
        return sorted(due, key=lambda c: c.seq)

    def pop_joints(self) -> list[JointCommandMsg]:
        """Every queued joint command, in tag order, removed from the buffer."""
        flushed = [self._joints[t] for t in self._joint_tags]
        self._joints.clear()
        self._joint_tags.clear()
        return flushed

    def pop_where(self, keep_out: Callable[[Command], bool]) -> list[Command]:
        """Every queued command for which ``keep_out`` is true, removed from the buffer, in
        tag order (seq order within a tag)."""
        removed: list[Command] = []
        for tag in [t for t in self._joint_tags if keep_out(self._joints[t])]:
            removed.append(self._joints.pop(tag))
        self._joint_tags = [t for t in self._joint_tags if t in self._joints]
        for tag in list(self._acs):
            out = [c for c in self._acs[tag] if keep_out(c)]
            if out:
                rest = [c for c in self._acs[tag] if not keep_out(c)]
                if rest:
                    self._acs[tag] = rest
                else:
                    del self._acs[tag]
                self._n_acs -= len(out)
                removed += out
        return sorted(removed, key=lambda c: (c.execute_time_ns, c.seq))

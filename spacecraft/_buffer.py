"""The onboard command buffer: accepted, not yet executed commands, ordered by time tag.

At most one joint command per tag (the vehicle refuses a second one before it gets here);
attitude-control commands may share a tag and then execute in seq order (the last wins).
"""

from __future__ import annotations

import bisect

from telemetry.wire import AcsCommandMsg, JointCommandMsg

__all__ = ["CommandBuffer"]

Command = JointCommandMsg | AcsCommandMsg


class CommandBuffer:
    def __init__(self) -> None:
        self._joints: dict[int, JointCommandMsg] = {}
        self._joint_tags: list[int] = []  # sorted
        self._acs: dict[int, list[AcsCommandMsg]] = {}

    def __len__(self) -> int:
        return len(self._joints) + sum(len(c) for c in self._acs.values())

    def add(self, command: Command) -> None:
        tag = command.execute_time_ns
        if isinstance(command, JointCommandMsg):
            self._joints[tag] = command
            bisect.insort(self._joint_tags, tag)
        else:
            self._acs.setdefault(tag, []).append(command)

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

    def pop_due(self, tag_ns: int) -> list[Command]:
        """The commands tagged exactly ``tag_ns``, in sequence order, removed from the buffer."""
        due: list[Command] = []
        joint = self._joints.pop(tag_ns, None)
        if joint is not None:
            self._joint_tags.remove(tag_ns)
            due.append(joint)
        due += self._acs.pop(tag_ns, [])
        return sorted(due, key=lambda c: c.seq)

    def pop_joints(self) -> list[JointCommandMsg]:
        """Every queued joint command, in tag order, removed from the buffer."""
        flushed = [self._joints[t] for t in self._joint_tags]
        self._joints.clear()
        self._joint_tags.clear()
        return flushed

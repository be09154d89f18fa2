"""GVSP frame ids (16-bit block ids) unwrapped to a monotonic 64-bit frame index.

GigE Vision 1.x block ids count 1..65535 and wrap to 1: the value 0 is never used (the Aravis fake camera starts at
65401). The unwrapper turns them into a monotonic counter and tells how many ids were skipped between two frames.
"""

from __future__ import annotations

#: number of distinct ids in a cycle (1..65535; 0 is skipped)
ID_CYCLE = 65535


def id_delta(previous_id: int, frame_id: int) -> int:
    """Forward distance from ``previous_id`` to ``frame_id`` (both 1..65535), in frames (1 = consecutive)."""
    if not (1 <= previous_id <= ID_CYCLE and 1 <= frame_id <= ID_CYCLE):
        raise ValueError(f"GVSP frame ids are 1..65535, got {previous_id}, {frame_id}")
    return (frame_id - previous_id) % ID_CYCLE


class FrameIdUnwrapper:
    """Turns 16-bit block ids into a frame index counted from the first frame seen (index 0).

    ``update(frame_id) -> (index, skipped)``: ``skipped`` is the number of ids missing since the previous frame
    (0 normally). A buffer that arrives late, behind newer ones (Aravis hands over a timed-out buffer after the
    next frames: at most ``LATE_WINDOW`` ids back), gets its own index back and ``skipped = -1``; it does not move
    the newest id, so the frames after it keep their indices. Any other repeated or backwards id (a camera reset) is
    reported with ``skipped = -1`` and takes the previous index + 1, so a reset cannot produce a huge fake gap.
    A buffer with id 0 (no id: its GVSP leader was lost) takes the next index and stands for the next id.
    """

    #: how far behind the newest id a buffer may arrive and still be a late buffer (not a camera reset)
    LATE_WINDOW = 256

    def __init__(self) -> None:
        self._last_id: int | None = None
        self._index = -1

    @property
    def last_index(self) -> int:
        """Index of the last frame seen (-1 before the first)."""
        return self._index

    def update(self, frame_id: int) -> tuple[int, int]:
        if frame_id == 0:
            # a buffer without an id (Aravis gives 0 when the frame's leader was lost): taken as the next id, so the
            # frame after it, with its own id, is not counted one further (a lost leader is not a lost frame)
            if self._last_id is not None:
                self._last_id = self._last_id % ID_CYCLE + 1
            self._index += 1
            return self._index, 0
        if self._last_id is None:
            self._last_id = frame_id
            self._index += 1
            return self._index, 0
        delta = id_delta(self._last_id, frame_id)
        behind = id_delta(frame_id, self._last_id) if delta else 0
        if delta > ID_CYCLE // 2 and 0 < behind <= min(self.LATE_WINDOW, self._index):
            return self._index - behind, -1  # a late buffer: its own place, the newest id stays
        self._last_id = frame_id
        if delta == 0 or delta > ID_CYCLE // 2:
            self._index += 1
            return self._index, -1
        self._index += delta
        return self._index, delta - 1

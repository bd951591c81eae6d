"""echo_suppressor in aec mode through a real graph: between two robot replies the mic's stamps
jump by 10 ms, less than stamp_tolerance_ms, so the node keeps the mic's timeline and the echo
path it learned is 10 ms off. The linear canceller sees its output louder than the mic, takes
that for an echo path change and relearns: the next reply still comes out cancelled (without
the relearning it froze as double talk and came out only 8-14 dB below the echo)."""

from __future__ import annotations

import numpy as np
import pytest
from audio_io.aec_node import BLOCK, RATE, T0, aec_node, reduction_db, samples_ns
from audio_io.synthetic_room import Room, recorded_speech
from std_msgs.msg import Bool

pytestmark = [pytest.mark.ros, pytest.mark.timeout(240)]

REPLY_S = 8
PAUSE_BLOCKS = 31  # ~1 s of quiet mic between the replies
MIC_JUMP_NS = 10_000_000  # 10 ms of mic never arrive: within the default stamp_tolerance_ms (20)
CONVERGED = (3 * RATE, 7 * RATE)  # the part of a reply compared (samples from its start)
LEAST_REDUCTION_DB = 25.0


@pytest.mark.ros
def test_a_mic_stamp_jump_between_replies_leaves_the_next_reply_cancelled(ros_namespace: str) -> None:
    far = recorded_speech(REPLY_S, RATE)
    mic = Room(delay_ms=30, reverb_ms=60, noise_dbfs=-90.0).echo(far, RATE)
    with aec_node(ros_namespace) as node:
        out = node.out

        node.wait_heard()
        reply_starts = []
        clock = T0
        quiet = np.zeros(BLOCK, dtype=np.int16)
        for reply in range(2):
            reply_starts.append(clock)
            node.speaking.publish(Bool(data=True))
            for k in range(0, len(far) // BLOCK * BLOCK, BLOCK):
                node.send(mic[k : k + BLOCK], clock + samples_ns(k), far[k : k + BLOCK])
            clock += samples_ns(len(far) // BLOCK * BLOCK)
            if reply == 0:
                node.speaking.publish(Bool(data=False))
                for k in range(PAUSE_BLOCKS):
                    if k == PAUSE_BLOCKS - 4:  # the next reply is announced before it plays
                        node.speaking.publish(Bool(data=True))
                    node.send(quiet, clock + samples_ns(k * BLOCK), None)
                clock += samples_ns(PAUSE_BLOCKS * BLOCK) + MIC_JUMP_NS
        # Flush the last blocks out: quiet mic (the reply is over) until the output reaches them.
        node.speaking.publish(Bool(data=False))
        for k in range(4):
            node.send(quiet, clock + samples_ns(k * BLOCK), None)

    first, second = (reduction_db(mic, out, start, *CONVERGED) for start in reply_starts)
    print(f"echo reduction through the node: first reply {first:.1f} dB, after the jump {second:.1f} dB")
    assert first >= LEAST_REDUCTION_DB
    assert second >= LEAST_REDUCTION_DB

"""rosbag2 bags with MCAP storage, written so that a SIGKILL leaves a readable bag.

Pure Python (rosbags for message definitions, CDR and reading); no rclpy.

>>> from damper_emulator.bag import BagWriter, Qos, messages, read_messages
>>> with BagWriter("bags/run1") as w:                                   # doctest: +SKIP
...     state = w.add_topic("/damper/state", "sensor_msgs/msg/JointState",
...                         qos=Qos(reliability="reliable", depth=10))
...     w.write(state, t_ns, messages.joint_state(t_ns, ["damper"], [x], [v], [f]))
>>> for topic, t_ns, msg in read_messages("bags/run1"):                  # doctest: +SKIP
...     ...
"""

from . import messages
from .messages import BagError
from .qos import Qos, Topic
from .reader import Bag, TopicInfo, open_bag, read_messages, topic_counts
from .writer import BagWriter

__all__ = [
    "Bag",
    "BagError",
    "BagWriter",
    "Qos",
    "Topic",
    "TopicInfo",
    "messages",
    "open_bag",
    "read_messages",
    "topic_counts",
]

"""damper-hil's damper: the Simms & Crolla model (:mod:`.model`), its parameters
(:mod:`.params`), the virtual dyno (:mod:`.dyno`), identification (:mod:`.identify`) and
diagnosis (:mod:`.diagnose`), the rig's measurement chain (:mod:`.acquisition`), the
emulator's real-time core (:mod:`.realtime`) and ROS shells (:mod:`.ros`), bags
(:mod:`.bag`) and their replay.  The bottom layer: it imports no other package of the
project."""

__version__ = "0.1.0"

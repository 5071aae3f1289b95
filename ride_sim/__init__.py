"""The quarter car: the vehicle (:mod:`.quarter_car`), roads (:mod:`.road`), ISO 2631
(:mod:`.iso2631`), the paper's studies (:mod:`.study`), tuning (:mod:`.tuning`), many cars
at once (:mod:`.many`) and the damper in the loop's cores (:mod:`.hybrid`).  Physics and
studies import no ROS; the ride node (:mod:`.node`) is the thin rclpy shell beside
:mod:`.session`."""

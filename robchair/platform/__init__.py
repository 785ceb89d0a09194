"""The chair's model, the ground floor of robchair beside :mod:`mapping`.

Platform spec (:mod:`robchair.platform.spec`, Table 9.1 and the mounts of ``assets/robchair.toml``),
frames (:mod:`robchair.platform.frames`), kinematics and odometry
(:mod:`robchair.platform.kinematics`), motor control design (:mod:`robchair.platform.control`), the
safety layer's limits and stops (:mod:`robchair.platform.safety`), config validation
(:mod:`robchair.platform.config`), errors (:mod:`robchair.platform.errors`) and asset paths
(:mod:`robchair.platform.paths`). Imports only :mod:`mapping` of the project; :mod:`hw` and
:mod:`sim` import this package and nothing else of robchair.
"""

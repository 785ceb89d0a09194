"""Navigation on the chair's own map: a grid planner with replanning, a route follower, the
classical baseline policy built from them, and the standard evaluation metrics."""

"""Viewers of a run folder that need the ``viz`` extra (``pip install 'robchair[viz]'``): the Rerun
recording (:mod:`robchair.viz.rerun_recording`)."""

"""Files a user keeps: run folders (:mod:`.runs`), atomic writes (:mod:`.files`), predictions and
meshes out (:mod:`.export`) and pictures (:mod:`.plots`)."""

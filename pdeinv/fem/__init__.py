"""Finite elements: meshes (:mod:`.mesh`), the assembled forms (:mod:`.forms`, :mod:`.advection`),
point sensors (:mod:`.sensors`), sparse solvers (:mod:`.solvers`) and the map between a mesh and
a regular grid (:mod:`.grid`). Nothing here knows about time stepping, training or torch."""

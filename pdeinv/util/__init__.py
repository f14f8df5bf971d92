"""Infrastructure every layer may use: the disk cache (:mod:`.cache`), memory estimates
(:mod:`.memory`), run-folder locks (:mod:`.runlock`) and thread pools (:mod:`.threads`). Nothing
here imports the rest of pdeinv."""

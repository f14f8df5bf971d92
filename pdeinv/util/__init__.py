"""Infrastructure every layer may use: the disk cache (:mod:`.cache`), memory estimates
(:mod:`.memory`), run-folder locks (:mod:`.runlock`), thread pools (:mod:`.threads`) and the old
module paths (:mod:`.moved`). Nothing here imports the rest of pdeinv."""

"""The one trainer and what it needs: the loop (:mod:`.trainer`), training rows and their seed
streams (:mod:`.trainset`, :mod:`.data`), targets (:mod:`.targets`), stopping rules
(:mod:`.stopping`), evaluation and the final verdict (:mod:`.evaluation`, :mod:`.unseen`,
:mod:`.verdict`), checkpoints (:mod:`.checkpoint`), ``torchrun`` (:mod:`.distributed`) and the
progress display (:mod:`.progress`)."""

"""The one trainer and what it needs: the loop (:mod:`.trainer`), checked entry-point arguments
(:mod:`.arguments`), training rows and their seed streams (:mod:`.trainset`, :mod:`.data`), stopping
rules (:mod:`.stopping`), the stages after the rule's (:mod:`.stages`), the plan of a run before it runs
(:mod:`.plan`), evaluation and the final verdict (:mod:`.evaluation`, :mod:`.verdict`),
the memory a run will hold (:mod:`.budget`), checkpoints (:mod:`.checkpoint`), ``torchrun``
(:mod:`.distributed`) and the classical references a run is compared with (:mod:`.references`)."""

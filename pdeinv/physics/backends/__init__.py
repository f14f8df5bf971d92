"""How a linear operator is applied once it is compiled: dense or SVD (:mod:`.compiled`,
:mod:`.lowrank`), modal (:mod:`.modal`, :mod:`.modes`) and on a torch device (:mod:`.device`)."""

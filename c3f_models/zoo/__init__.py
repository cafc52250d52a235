"""The model zoo's training side: recipes (:mod:`.recipes`), running them resumably
(:mod:`.train`), packaging, evaluation and model cards (:mod:`.package`, :mod:`.evaluate`,
:mod:`.card`) and ``python -m c3f_models zoo`` (:mod:`.cli`). Reading the zoo needs no torch:
:mod:`c3f_slam.models.zoo`."""

"""Stage 3: a model and a new image become probes of p(w) (Fig. 2): the search's setup
(:mod:`~posevote.inference.setup`), its votes (:mod:`~posevote.inference.voting`), the
search itself (:mod:`~posevote.inference.search`), its output
(:mod:`~posevote.inference.probes`) and the coverage re-ranking
(:mod:`~posevote.inference.coverage`)."""

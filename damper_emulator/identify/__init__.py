"""Identification of the model's parameters from dyno tests: the quasi-static friction and
gas force (:mod:`.quasi_static`), the valves from the chirp (:mod:`.valves`), the fitting
tools (:mod:`.fitting`), the pipeline the command line runs (:mod:`.pipeline`) and its
report (:mod:`.report`)."""

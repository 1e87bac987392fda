"""Workflows: the one layer that composes protocol, engine, store, analysis and report.

Each module here is a use case a command runs end to end; the layers below never import it:

* :mod:`~studyctl.workflows.simulate`: a cohort of seeded virtual participants run through the engine;
* :mod:`~studyctl.workflows.report`: plan → analysis → figure data → report folder (``studyctl report``);
* :mod:`~studyctl.workflows.power`: a power analysis run, its files and its power-curve figure;
* :mod:`~studyctl.workflows.demo`: the four reference studies simulated, analysed and reported.

Nothing is imported here, so the CLI can import one workflow without loading the others.
"""

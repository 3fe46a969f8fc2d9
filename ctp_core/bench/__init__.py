"""The evaluation harness behind ``ctp bench``: cases, the perturbation protocol, baselines, the run
loop and the summary. See ``harness.run_bench`` for the entry point.
"""

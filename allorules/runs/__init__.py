"""Runs: the pipeline every front end calls (prepare, label, scale, save, report), global and
ruleset runs in steps, local scaling, batch runs, the demo and progress reporting.
"""

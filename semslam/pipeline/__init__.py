"""Runs that touch files, one module per command: read inputs, call the library, write
outputs atomically, show progress, leave the configuration beside the results.

Library modules elsewhere compute and do no I/O; ``semslam.cli`` only wires
arguments to the functions here.
"""

"""The robot, graph and fault math: numpy only, no engine.

The unicycle and its wheels (``robot``), adjacency matrices (``graphs``) and the registry of
graph kinds (``topologies``), the experts' laws (``experts``), the minimum enclosing circle
(``mec``), metrics and the lower bound (``metrics``), random starts (``initial_poses``), and
the fault kinds with the one message-selection rule (``faults``). And the exit statuses of every command line
(``exit_codes``), defined once here, below every layer that uses them. Imports nothing else of the
project: every other package builds on this one.
"""

"""The command line, a package above the library: one argparse tree (``cli.main``) of
commands (run, nodes, bag, replay, keys), one module each; ``launch.py`` and the
``softbubble`` command are its entry points.

Imports flow one way: ``cli`` imports ``nodes``, ``runtime`` and ``viz``; nothing below it
imports ``cli`` (``python -c "import runtime"`` loads no command-line module).
"""

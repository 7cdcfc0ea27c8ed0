"""What each command does, as library calls: configs in, result objects with tables and ``.save(dir)`` out.

Re-exported by :mod:`mcfdd`; the ``mcfdd`` command is argument parsing over these.
"""

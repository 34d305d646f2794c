"""``python -m training run`` (``make run``): the appliance live on this machine (cli.py), its
child processes in a process group of their own (procs.py) and the summary (summary.py)."""

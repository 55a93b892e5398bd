"""scripts/soak.sh (rosrun ecar_sim soak): light devices for minutes against one server, with
faults injected, and what it proves: server memory over time, acknowledged VOs lost, crashes,
every device recovering by itself, hostile inputs rejected.

    options.py  the command line
    ledger.py   every acknowledged VO change, checked against the SQLite database
    memory.py   resident memory of the server and the devices over time, growth per server life
    editor.py   a VO client (register, manipulate, delete) that stays connected
    hostile.py  the hostile and malformed inputs mixed in, each with its expected rejection
    faults.py   kill -9 of the server, restart of the devices, the database's disk full
    runner.py   the whole run and its report (summary.json, memory.csv, memory.png, REPORT.md)
"""

"""``riskfield bench NAME`` runs ``riskfield.experiments.benches.NAME.app`` (a typer app printing a table
and writing ``summary.json`` under ``--out``)."""

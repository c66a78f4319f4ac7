from riskfield.cli import app

app(prog_name="riskfield")

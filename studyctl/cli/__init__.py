"""Thin typer commands: parse, call one library function, render. No SQL, numpy or YAML here."""

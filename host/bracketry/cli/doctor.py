"""``bracketry doctor``: report each component with its version, or a one-line fix; exit 0 only if all are present."""

from __future__ import annotations

import json

import click

from bracketry_rig.doctor import run_all


@click.command("doctor")
@click.option("--json", "as_json", is_flag=True, help="Print the checks as JSON.")
def command(as_json: bool) -> int:
    """Check that every component the rig and the tests need is here (exit 1 if any is missing)."""
    checks = run_all()
    if as_json:
        click.echo(json.dumps([c.__dict__ for c in checks], indent=2))
    else:
        width = max(len(c.name) for c in checks)
        for c in checks:
            if c.ok:
                click.echo(f"  ok       {c.name:<{width}}  {c.version}")
            else:
                click.echo(f"  MISSING  {c.name:<{width}}  fix: {c.fix}")
        missing = sum(not c.ok for c in checks)
        click.echo(f"{len(checks) - missing}/{len(checks)} components present")
    return 0 if all(c.ok for c in checks) else 1

"""Validates run configurations (TOML) against chaoscope's JSON Schema with a third-party
validator (jsonschema), as a TOML editor that takes a schema would.

    check_schema.py SCHEMA.json --valid A.toml ... --invalid B.toml ...

Prints one line per file; exits 1 if a --valid file is refused or an --invalid one accepted.
"""

import json
import sys
import tomllib

import jsonschema


def main(argv):
    schema = json.load(open(argv[0]))
    validator = jsonschema.validators.validator_for(schema)
    validator.check_schema(schema)
    check = validator(schema)
    expect, failures = None, 0
    for arg in argv[1:]:
        if arg in ("--valid", "--invalid"):
            expect = arg == "--valid"
            continue
        with open(arg, "rb") as f:
            config = tomllib.load(f)
        errors = sorted(check.iter_errors(config), key=lambda e: list(e.absolute_path))
        ok = not errors
        first = errors[0] if errors else None
        where = "/".join(str(p) for p in first.absolute_path) if first else ""
        print(f"{'valid' if ok else 'refused'}: {arg}" + (f" at {where}: {first.message}" if first else ""))
        if ok != expect:
            failures += 1
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

"""The reproduction's CSV files: rows written with a fixed header, read back with numbers typed."""

import csv


def write_rows(path, fields, rows):
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows(rows)


def parse(text):
    """A CSV cell: text stays text, numbers become int or float, empty None."""
    if text == "":
        return None
    try:
        return int(text)
    except ValueError:
        try:
            return float(text)
        except ValueError:
            return text


def parse_rows(path):
    with open(path) as f:
        return [{k: parse(v) for k, v in r.items()} for r in csv.DictReader(f)]

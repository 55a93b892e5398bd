#!/usr/bin/env python3
"""Prints the closing line 'N passed, N failed, N skipped' over JUnit XML results."""
import pathlib
import sys
import xml.etree.ElementTree as ET


def main(root):
    passed = failed = skipped = 0
    for path in pathlib.Path(root).rglob("*.xml"):
        try:
            tree = ET.parse(path)
        except ET.ParseError:
            failed += 1
            print(f"unreadable test result: {path}")
            continue
        for case in tree.getroot().iter("testcase"):
            if case.find("failure") is not None or case.find("error") is not None:
                failed += 1
            elif case.find("skipped") is not None or case.get("status") == "notrun":
                skipped += 1
            else:
                passed += 1
    print(f"{passed} passed, {failed} failed, {skipped} skipped")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "build/test_results")

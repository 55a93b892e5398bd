#!/usr/bin/env python3
"""Prints the closing line 'N passed, N failed, N skipped' over JUnit XML results.

Each failed case is printed first with its file and the start of its failure message, so a CI
log that only keeps the tail still says what failed and why.
"""
import pathlib
import sys
import xml.etree.ElementTree as ET

MESSAGE_CHARS = 1500


def main(root):
    passed = failed = skipped = 0
    for path in sorted(pathlib.Path(root).rglob("*.xml")):
        try:
            tree = ET.parse(path)
        except ET.ParseError:
            failed += 1
            print(f"unreadable test result: {path}")
            continue
        for case in tree.getroot().iter("testcase"):
            problem = case.find("failure")
            if problem is None:
                problem = case.find("error")
            if problem is not None:
                failed += 1
                text = (problem.get("message") or "") + "\n" + (problem.text or "")
                text = text.strip()[:MESSAGE_CHARS]
                print(f"FAILED {path.name}: {case.get('classname')}.{case.get('name')}")
                for line in text.splitlines():
                    print(f"    {line}")
            elif case.find("skipped") is not None or case.get("status") == "notrun":
                skipped += 1
            else:
                passed += 1
    print(f"{passed} passed, {failed} failed, {skipped} skipped")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "build/test_results")

#!/usr/bin/env python3
"""Counts test cases in the JUnit XML files under a directory and prints one closing line:
'tests: N passed, F failed, S skipped'. (catkin_test_results counts each gtest case twice.)"""
import pathlib
import sys
import xml.etree.ElementTree as ElementTree


def main():
    root = pathlib.Path(sys.argv[1] if len(sys.argv) > 1 else ".")
    passed = failed = skipped = 0
    for path in sorted(root.rglob("*.xml")):
        try:
            tree = ElementTree.parse(path)
        except ElementTree.ParseError as error:
            print(f"{path}: unreadable test result ({error})")
            failed += 1
            continue
        for case in tree.iter("testcase"):
            if case.find("failure") is not None or case.find("error") is not None:
                failed += 1
            elif case.find("skipped") is not None or case.get("status") == "notrun":
                skipped += 1
            else:
                passed += 1
    print(f"tests: {passed} passed, {failed} failed, {skipped} skipped")
    return 1 if failed or passed == 0 else 0


if __name__ == "__main__":
    sys.exit(main())

"""pytest plugin: scenario files with an ``expect:`` block become test items.

Registered through the ``pytest11`` entry point. Implementation in progress (issue 5):
until then it collects nothing.
"""

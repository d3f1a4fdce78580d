"""The neutral bottom layer: bounded YAML reading with line numbers and the safe expression
evaluator. Imported by ``diagram/`` and ``multibody/``; imports nothing of spidersim but
:mod:`spidersim.errors`.

Limits (:mod:`spidersim.text.limits`) bound every file and expression read, so that a
hostile input is refused with a clear error instead of exhausting memory or the stack.
"""

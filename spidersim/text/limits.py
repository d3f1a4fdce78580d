"""Bounds on every diagram file and expression spidersim reads.

Generous for real diagrams (the full ``spider.yaml`` with its subsystems uses well under 1 %
of each) and small enough that a hostile file is refused in milliseconds with a few MB of
memory. Each limit is named in the error that enforces it.
"""

#: bytes in one YAML file (diagram, subsystem, arm data)
MAX_FILE_BYTES = 2_000_000
#: YAML nodes (scalars, lists, mappings) after aliases are expanded
MAX_NODES = 200_000
#: alias references (``*name``) in one file
MAX_ALIASES = 1_000
#: nesting depth of lists and mappings
MAX_DEPTH = 64
#: elements of one list or entries of one mapping
MAX_ITEMS = 100_000
#: characters of one scalar string
MAX_STRING = 100_000
#: characters of one expression such as ``2*pi*955/60``
MAX_EXPR_CHARS = 2_000
#: nesting depth of an expression's syntax tree
MAX_EXPR_DEPTH = 50
#: elements of an evaluated vector or matrix parameter
MAX_ARRAY_ELEMENTS = 1_000_000
#: subsystem instances nested inside each other (a subsystem file that uses a subsystem
#: that uses ...; spider.yaml nests 2 deep). Deeper chains are refused before the next
#: file is read: a chain of 3,000 files once failed deep in the YAML reader, blaming one
#: file of the chain
MAX_SUBSYSTEM_DEPTH = 32
#: primitive blocks of one diagram after its subsystems are expanded (compile time and
#: memory grow faster than the count: 1,200 chained Gains compile in about 23 s and 1.5 GB,
#: 2,000 in 73 s and 3.7 GB, 5,000 did not fit in 4 GB; spider.yaml has 74); also stops a
#: subsystem "fan-out bomb" (ten instances of ten instances of ...)
MAX_BLOCKS = 2_000

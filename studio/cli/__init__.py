"""``shadow-studio <verb>``: one module per verb group; ``main`` builds the parser.

The only engine modules that print.
"""

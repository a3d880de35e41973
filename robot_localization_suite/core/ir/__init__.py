"""Information-retrieval global initialisation, Aycard & Brouard (``ir_initializer``); see docs/ir.md."""

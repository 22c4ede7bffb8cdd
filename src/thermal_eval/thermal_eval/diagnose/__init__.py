"""Concealed-effect recordings and the suites that score the mismatch finder."""

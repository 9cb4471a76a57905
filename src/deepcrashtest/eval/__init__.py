"""deepcrashtest.eval"""

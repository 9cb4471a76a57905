"""deepcrashtest.search"""

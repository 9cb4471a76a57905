"""deepcrashtest.export"""

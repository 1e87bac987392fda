"""studyctl.stats"""

"""studyctl.store"""

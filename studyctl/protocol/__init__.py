"""studyctl.protocol"""

"""studyctl.analysis"""

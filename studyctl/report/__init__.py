"""studyctl.report"""
